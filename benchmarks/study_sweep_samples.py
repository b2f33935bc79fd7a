"""How the sweep's sampled distance-error bound converges with the number of clearance
states M (`torchcal sweep --samples M`), on three robots.

The sweep's upper bound at a point is the largest |e| over the M sampled clearance states
(plus the nominal one): a sample maximum, so it is below the true largest error and grows
with M. This study measures by how much, to pick the sample count below which
`torchcal sweep` warns (`torchcal.reliability.sweep.MIN_SAMPLES`).

- robots: the kr1000titan preset with its default clearance model (docs/paper.md Table 2,
  `ClearanceModel.defaults`); the ur5e and puma560 presets, which have none, with the same
  Table 2 clearances (mm) and the bearing lengths (the KR 1000's, = shaft diameter) scaled
  by the arm's size (its full stretch, `torchcal.robots.workspace.arm_stretch`) over the
  KR 1000's: a small arm's seats sit closer, so the same clearance tilts its axes more;
- points: N = 200 workspace points per robot (`sample_workspace`, seed 0, no keep-out column);
- reference: the largest distance error the clearance states allow at each point, found
  by coordinate ascent on the first-order error e = J(q) D u (J the position Jacobian of
  the MD-H deviations, D `deviation_map`, u the seat offsets with |u_k| = c_k): each
  seat's direction in turn set to the best of 720 angles, 30 sweeps over the seats, 8
  random starts, the best kept (a local maximum: a lower bound of the true one). The
  first-order error agrees with the sweep's full FK (printed). The
  sampled bound of M_REF = 20000 states (seed 0) is printed against it: the sample maximum
  converges slowly (the states fill a 2n-dimensional torus);
- for M in COUNTS and sweep seeds 0..4 (fresh states per seed), the shortfall
  1 - bound(M) / largest per point; printed: the median over points and seeds, and the
  95th percentile over points (median over seeds), per robot and M.

    TORCHCAL_THREADS=1 nice -n 5 python benchmarks/study_sweep_samples.py
"""

from __future__ import annotations

import numpy as np
import torch

import torchcal
from torchcal.reliability.sweep import sweep
from torchcal.kinematics import mdh as K
from torchcal.reliability.uncertainty import (KR1000_BEARING_LENGTH_MM, KR1000_CLEARANCE_MM, KR1000_RADII_MM,
                                              ClearanceModel, deviation_map, sample_states)
from torchcal.robots.workspace import Workspace, arm_stretch as stretch, sample_workspace

COUNTS = (1, 2, 3, 5, 10, 20, 30, 50, 100, 200, 300, 1000, 3000)
M_REF = 20000
SEEDS = range(5)
N = 200


def clearance(robot, kr) -> ClearanceModel:
    if robot.name == "kr1000titan":
        return ClearanceModel.defaults(robot)
    s = stretch(robot) / stretch(kr)
    return ClearanceModel([r * s for r in KR1000_RADII_MM], KR1000_CLEARANCE_MM,
                          [b * s for b in KR1000_BEARING_LENGTH_MM])


def largest_error(robot, model, q, starts: int = 8, sweeps: int = 30, angles: int = 720, seed: int = 1):
    """(N,) mm: the largest first-order |e| over the clearance states at q (N, n), by
    coordinate ascent over the seat directions (module doc)."""
    G = (K.param_jacobian(q, robot.chain) @ deviation_map(robot, model)).numpy()  # (N, 3, 4n)
    N, seats = q.shape[0], 2 * robot.n
    Gk = G.reshape(N, 3, seats, 2)
    c = np.array(model.clearance_mm)
    phi = np.linspace(0, 2 * np.pi, angles, endpoint=False)
    circle = np.stack([np.cos(phi), np.sin(phi)], 1)  # (A, 2)
    rng = np.random.default_rng(seed)
    best = np.zeros(N)
    for _ in range(starts):
        a = rng.uniform(0, 2 * np.pi, (N, seats))
        u = c[None, :, None] * np.stack([np.cos(a), np.sin(a)], -1)  # (N, seats, 2)
        for _ in range(sweeps):
            for k in np.flatnonzero(c > 0):
                rest = np.einsum("nikc,nkc->ni", Gk, u) - np.einsum("nic,nc->ni", Gk[:, :, k], u[:, k])
                cand = rest[:, None, :] + c[k] * np.einsum("nic,ac->nai", Gk[:, :, k], circle)
                u[:, k] = c[k] * circle[np.linalg.norm(cand, axis=-1).argmax(1)]
        best = np.maximum(best, np.linalg.norm(np.einsum("nikc,nkc->ni", Gk, u), axis=-1))
    return torch.from_numpy(best)


def first_order_gap(robot, model, q, m: int = 300) -> float:
    """Largest relative difference between the first-order and the sweep's distance bound."""
    G = (K.param_jacobian(q, robot.chain) @ deviation_map(robot, model)).reshape(q.shape[0], 3, -1)
    u = sample_states(model, m, torch.Generator().manual_seed(0)).reshape(m, -1)
    lin = torch.einsum("nij,mj->nmi", G, u).norm(dim=-1).amax(1)
    full = sweep(robot, q, n_samples=m, seed=0, model=model, linear=False).dist_upper
    return float((lin / full - 1).abs().max())


def main() -> None:
    kr = torchcal.robot("kr1000titan")
    for name in ("kr1000titan", "ur5e", "puma560"):
        robot = torchcal.robot(name)
        model = clearance(robot, kr)
        q = sample_workspace(robot, N, seed=0, workspace=Workspace(column_radius_mm=0.0))

        def bound(m, seed):
            return sweep(robot, q, n_samples=m, seed=seed, model=model, linear=False).dist_upper

        ref = largest_error(robot, model, q)
        big = bound(M_REF, 0)
        print(f"{name}: stretch {stretch(robot):.1f} mm; largest error {float(ref.min()):.3f} .. {float(ref.max()):.3f} mm "
              f"(first order vs full FK within {100 * first_order_gap(robot, model, q):.2f} %); M={M_REF} states "
              f"{100 * float((1 - big / ref).median()):.1f} % under it (median point), "
              f"{100 * float((1 - big / ref).min()):.1f} .. {100 * float((1 - big / ref).max()):.1f} %")
        print("   M   shortfall % median   p95 over points   worst point")
        for m in COUNTS:
            short = torch.stack([1 - bound(m, s) / ref for s in SEEDS])  # (seeds, N)
            p95 = torch.quantile(short, 0.95, dim=1).median()
            print(f"{m:5d}   {100 * float(short.median()):8.1f}          {100 * float(p95):8.1f}       "
                  f"{100 * float(short.max()):8.1f}")


if __name__ == "__main__":
    main()
