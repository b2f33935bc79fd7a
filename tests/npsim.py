"""Independent plain-numpy reference simulator for tests: the MD-H chain written out
(A_i = Rz Tz Tx Rx Ry, a prismatic joint's q adds to d), a tracker frame, a reflector on
the flange and a joint-2 deflection, none of it through torchcal's kernels or effects."""

from __future__ import annotations

import numpy as np


def _rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _rx(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1.0, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])


def _ry(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0, s, 0], [0, 1.0, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]])


def _tr(x, z):
    T = np.eye(4)
    T[0, 3], T[2, 3] = x, z
    return T


def numpy_fk(robot, q, dev, tool=None):
    """TCP positions (N, 3) mm of `robot` (its table, joint types, base, tool) with MD-H
    deviations dev (n, 5) [dtheta rad, dd mm, da mm, dalpha rad, dbeta rad] at q (N, n)
    rad (mm for a slide). tool: (4, 4) flange <- TCP replacing the robot's, or None."""
    table = robot.table.numpy() + dev
    pris = robot.prismatic.numpy().astype(bool)
    tool = robot.tool.numpy() if tool is None else np.asarray(tool, dtype=float)
    out = []
    for qq in np.asarray(q, dtype=float):
        T = robot.base.numpy().copy()
        for (th, d, a, al, be), qj, p in zip(table, qq, pris):
            T = T @ _rz(th + (0.0 if p else qj)) @ _tr(0.0, d + (qj if p else 0.0)) @ _tr(a, 0.0) @ _rx(al) @ _ry(be)
        out.append((T @ tool)[:3, 3])
    return np.array(out)


def tracker_session(robot, q, seed, distance_mm=3000.0, reflector_mm=(0.0, 0.0, 290.0), sag_deg=0.05,
                    noise_mm=0.02, dev_scale=(0.2, 0.03)):
    """A "real" robot seen by a laser tracker: small seeded MD-H deviations (dev_scale:
    largest |dd|, |da| mm and |dtheta|, |dalpha| deg), a hidden joint-2 sag of sag_deg * cos(q2)
    (gravity-like, not an effect of the fitted model unless asked), a reflector
    `reflector_mm` on the flange instead of the robot's tool, a tracker frame turned and
    `distance_mm` away, Gaussian noise. q (N, n) rad -> xyz (N, 3) mm in the tracker frame."""
    rng = np.random.default_rng(seed)
    n = robot.n
    dev = np.zeros((n, 5))
    dev[:, [1, 2]] = rng.uniform(-1, 1, (n, 2)) * dev_scale[0]
    dev[:, [0, 3]] = np.radians(rng.uniform(-1, 1, (n, 2)) * dev_scale[1])
    q = np.asarray(q, dtype=float).copy()
    q[:, 1] = q[:, 1] + np.radians(sag_deg) * np.cos(q[:, 1])
    tool = np.eye(4)
    tool[:3, 3] = reflector_mm  # flange <- reflector
    p = numpy_fk(robot, q, dev, tool=tool)
    a = rng.uniform(0, 2 * np.pi)
    R = _rz(a)[:3, :3] @ _rx(np.radians(rng.uniform(-3, 3)))[:3, :3]
    t = np.array([distance_mm * np.cos(a), distance_mm * np.sin(a), -500.0])
    return p @ R.T + t + rng.normal(0, noise_mm, p.shape)
