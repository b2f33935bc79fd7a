"""Choice of the damping mu of eq. 29 by generalised cross-validation (Golub, Heath & Wahba 1979).

Used by `torchcal.calibration.intervals.identify_zones` with ``damping="gcv"`` (one mu per
zone) or ``"gcv_shared"`` (one mu for every zone). mu is relative to the squared column
norms of the Jacobian (scale-invariant damping, as in `torchcal.calibration.intervals.solution_map`).
"""

from __future__ import annotations

import warnings

import torch

__all__ = ["GCV_GRID", "DampingWarning", "gcv_damping", "choose_damping"]


class DampingWarning(UserWarning):
    """GCV chose the largest damping of its grid: it would damp further (see `choose_damping`)."""


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


def choose_damping(J: torch.Tensor, r: torch.Tensor, free: torch.Tensor, mode: str, grid=GCV_GRID,
                   labels=None) -> list[float]:
    """mu per zone by GCV: J B Jacobians (R_b, P), r B errors (R_b,), free (B, P) bool
    (stacked tensors or sequences: zones may have different numbers of rows).

    mode ``"gcv"``: each zone its own grid value; ``"gcv_shared"``: one value for every
    zone, the one with the smallest sum of the zones' GCV. Returns B floats.

    A choice at the top of the grid is a bound, not a minimum: GCV would damp further, the
    zone's poses barely move its parameters from the start (the global calibration), and
    the interval is that of the damped solution. One `DampingWarning` names the zones
    (`labels`, default "zone 1", ...) and the bound. The bottom of the grid, 0 (no
    damping), is the end of the range, not a cut.
    """
    labels = [f"zone {b + 1}" for b in range(len(J))] if labels is None else list(labels)
    scores = [gcv_damping(J[b], r[b], free[b], grid) for b in range(len(J))]
    if mode == "gcv":
        mus = [sc[0] for sc in scores]
    else:
        tot = [sum(sc[1][i] for sc in scores) for i in range(len(grid))]
        mus = [float(grid[min(range(len(tot)), key=tot.__getitem__)])] * len(scores)
    top = float(max(grid))
    at_top = [lab for lab, mu in zip(labels, mus) if mu == top and top > 0]
    if at_top:
        which = "the damping shared by the zones" if mode == "gcv_shared" else "the damping"
        names = ", ".join(at_top[:6]) + (f" and {len(at_top) - 6} more" if len(at_top) > 6 else "")
        warnings.warn(DampingWarning(
            f"{names}: {which} chosen by GCV is {top:g}, the top of its grid ({float(min(grid)):g}..{top:g}): GCV "
            f"would damp further; the poses barely move the parameters from the global calibration (their errors "
            f"are the global model's, or too few poses to tell), and each interval is the damped solution's"),
            stacklevel=3)
    return mus
