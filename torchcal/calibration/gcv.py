"""Choice of the damping mu of eq. 29 by generalised cross-validation (Golub, Heath & Wahba 1979).

Used by `torchcal.calibration.intervals.identify_zones` with ``damping="gcv"`` (one mu per
zone) or ``"gcv_shared"`` (one mu for every zone). mu is relative to the squared column
norms of the Jacobian (scale-invariant damping, as in `torchcal.calibration.intervals.solution_map`).
"""

from __future__ import annotations

import torch

__all__ = ["GCV_GRID", "gcv_damping", "choose_damping"]


#: damping values tried by ``damping="gcv"`` (relative to the squared column norms).
GCV_GRID = (0.0, 1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 1e-1, 3e-1, 1.0, 3.0, 10.0)


def gcv_damping(J: torch.Tensor, r: torch.Tensor, free: torch.Tensor, grid=GCV_GRID) -> tuple[float, list]:
    """Damping mu of eq. 29 chosen by generalised cross-validation (Golub, Heath & Wahba 1979).

    For the linearised problem ``r ~ J dx`` (J (R, P) at the starting point, r (R,) the
    errors there), the damped solution ``dx = (J_f^T J_f + mu D^2)^-1 J_f^T r`` has the hat
    matrix H(mu) = J_f (J_f^T J_f + mu D^2)^-1 J_f^T and
    ``GCV(mu) = R |r - H r|^2 / (R - tr H)^2``, an estimate of the prediction error at new
    poses. Returns the grid value with the smallest GCV and the list of GCV values.
    """
    idx = free.to(J.device).nonzero().flatten()
    Jf = J[:, idx]
    d = Jf.norm(dim=0).clamp_min(1e-300)
    U, sv, _ = torch.linalg.svd(Jf / d, full_matrices=False)
    ur = U.T @ r  # (k,)
    out = []
    R = r.shape[0]
    rr = float(r @ r)
    for mu in grid:
        f = sv ** 2 / (sv ** 2 + mu)  # filter factors
        rss = rr - float(((2 * f - f ** 2) * ur ** 2).sum())
        dof = R - float(f.sum())
        out.append(R * max(rss, 0.0) / dof ** 2 if dof > 1e-9 else float("inf"))
    best = min(range(len(grid)), key=lambda i: out[i])
    return float(grid[best]), out


def choose_damping(J: torch.Tensor, r: torch.Tensor, free: torch.Tensor, mode: str, grid=GCV_GRID) -> list[float]:
    """mu per zone by GCV: J B Jacobians (R_b, P), r B errors (R_b,), free (B, P) bool
    (stacked tensors or sequences: zones may have different numbers of rows).

    mode ``"gcv"``: each zone its own grid value; ``"gcv_shared"``: one value for every
    zone, the one with the smallest sum of the zones' GCV. Returns B floats.
    """
    scores = [gcv_damping(J[b], r[b], free[b], grid) for b in range(len(J))]
    if mode == "gcv":
        return [sc[0] for sc in scores]
    tot = [sum(sc[1][i] for sc in scores) for i in range(len(grid))]
    return [float(grid[min(range(len(tot)), key=tot.__getitem__)])] * len(scores)
