"""Independent two-step reference for the UR10 example (numpy / scipy only, no torchcal).

1. Register: closed-form rigid fit (Kabsch) of the nominal model's TCP points onto the
   measured training points (measurement frame <- robot base).
2. Fit the geometry: base frame (6), tool offset (3) and the MD-H deviations of every
   joint [dtheta, dd, da, dalpha (, dbeta where the robot file declares beta)], position
   only, by scipy.optimize.least_squares from the registered start. Parameters that the
   training poses cannot separate are held at their start value: QR with column pivoting
   of the column-normalised Jacobian at the start, relative tolerance 1e-8.

Prints, per split, the validation RMS of the distance error (mm) of the registered
nominal model and of the fitted model. MD-H link transform: A = Rz(theta) Tz(d) Tx(a)
Rx(alpha) Ry(beta) (docs/robots.md), q in degrees in the files.

Usage: python two_step.py ROBOT.json TRAIN.csv VAL.csv
"""

import argparse
import csv
import json

import numpy as np
from scipy.linalg import qr
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation


def read(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    q = np.radians([[float(r[f"q{k}"]) for k in range(1, 7)] for r in rows])
    xyz = np.array([[float(r[c]) for c in "xyz"] for r in rows])
    return q, xyz


def fk(q, table, tool_t, R=np.eye(3), t=np.zeros(3)):
    """TCP positions (N, 3) mm: table (6, 5) [theta_off, d, a, alpha, beta] rad / mm."""
    N = q.shape[0]
    T = np.tile(np.eye(4), (N, 1, 1))
    for i in range(table.shape[0]):
        th, d, a, al, be = table[i]
        c, s = np.cos(q[:, i] + th), np.sin(q[:, i] + th)
        ca, sa, cb, sb = np.cos(al), np.sin(al), np.cos(be), np.sin(be)
        A = np.zeros((N, 4, 4))
        # Rz(theta) Tz(d) Tx(a) Rx(alpha) Ry(beta)
        RxRy = np.array([[cb, 0, sb], [sa * sb, ca, -sa * cb], [-ca * sb, sa, ca * cb]])
        Rz = np.zeros((N, 3, 3))
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1
        A[:, :3, :3] = Rz @ RxRy
        A[:, :3, 3] = (Rz @ np.array([a, 0.0, d]))
        A[:, 3, 3] = 1
        T = T @ A
    p = (T[:, :3, :3] @ tool_t) + T[:, :3, 3]
    return p @ R.T + t


def kabsch(src, dst):
    """R, t minimising |R src + t - dst|."""
    cs, cd = src.mean(0), dst.mean(0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cd - R @ cs


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("robot")
    ap.add_argument("train")
    ap.add_argument("val")
    args = ap.parse_args()
    rob = json.load(open(args.robot))
    table = np.array([[np.radians(j["theta_offset_deg"]), j["d_mm"], j["a_mm"], np.radians(j["alpha_deg"]),
                       np.radians(j.get("beta_deg", 0.0))] for j in rob["joints"]])
    has_beta = [("beta_deg" in j) for j in rob["joints"]]
    tool0 = np.array(rob["tool"])[:3, 3]
    qt, xt = read(args.train)
    qv, xv = read(args.val)

    R0, t0 = kabsch(fk(qt, table, tool0), xt)
    reg_val = np.sqrt((np.linalg.norm(fk(qv, table, tool0, R0, t0) - xv, axis=1) ** 2).mean())

    # parameter vector: base rotvec (3, about the Kabsch start), base t (3), tool (3), deviations
    dev_idx = [(i, k) for i in range(6) for k in range(5) if k < 4 or has_beta[i]]

    def unpack(x):
        R = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
        t = t0 + x[3:6]
        tool = tool0 + x[6:9]
        tab = table.copy()
        for v, (i, k) in zip(x[9:], dev_idx):
            tab[i, k] += v
        return tab, tool, R, t

    def resid(x, q, xyz):
        tab, tool, R, t = unpack(x)
        return (fk(q, tab, tool, R, t) - xyz).ravel()

    P = 9 + len(dev_idx)
    x0 = np.zeros(P)
    # identifiability at the registered start: finite-difference Jacobian, pivoted QR
    h = np.where(np.arange(P) < 3, 1e-6, 1e-4)
    h[9:] = [1e-6 if k in (0, 3, 4) else 1e-4 for _, k in dev_idx]
    r0 = resid(x0, qt, xt)
    J = np.stack([(resid(x0 + h[j] * np.eye(P)[j], qt, xt) - r0) / h[j] for j in range(P)], axis=1)
    nrm = np.linalg.norm(J, axis=0)
    Jn = J / np.where(nrm > 0, nrm, 1.0)  # a column without effect is held (rank test)
    _, Rq, piv = qr(Jn, mode="economic", pivoting=True)
    d = np.abs(np.diag(Rq))
    rank = int((d > 1e-8 * d[0]).sum())
    free = np.sort(piv[:rank])

    def resid_free(z):
        x = x0.copy()
        x[free] = z
        return resid(x, qt, xt)

    sol = least_squares(resid_free, np.zeros(len(free)), x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    x = x0.copy()
    x[free] = sol.x
    tab, tool, R, t = unpack(x)
    train = np.sqrt((resid(x, qt, xt).reshape(-1, 3) ** 2).sum(1).mean())
    val = np.sqrt((np.linalg.norm(fk(qv, tab, tool, R, t) - xv, axis=1) ** 2).mean())
    print(f"{args.train}: registered nominal val rms {reg_val:.4f} mm; two-step fit ({rank} of {P} parameters "
          f"free): train rms {train:.4f} mm, val rms {val:.4f} mm")


if __name__ == "__main__":
    main()
