"""Worst-case distance-error bounds of the sweep over the whole clearance set (`sweep(...,
bounds="worst")`, ``torchcal sweep --bounds worst``; docs/scale.md "Worst-case bounds").

The sampled bound of a point (the largest |e| of M clearance states) is a sample maximum:
below the largest error the clearance allows, by 21-31 % at the median point with M = 300
(benchmarks/study_sweep_samples.py). Here the error is taken to first order in the seat
offsets, as the deviations themselves are (`torchcal.reliability.uncertainty.deviation_map`):

    e(u, t) = sum_k G_k u_k + sum_i J_i t_i          (mm, world frame)

with J (3, 5n) the position Jacobian of the MD-H deviations at the point, G_k = J D_k
(3, 2) the columns of seat k (D the deviation map), u_k (2,) mm the offset of seat k,
|u_k| <= c_k (= c_k in the "contact" mode: the largest |e| over a disc lies on its rim, |e|
being convex, so both modes have the same bounds), and t_i the tolerance box's deviation i,
|t_i| <= tol_i (none unless the model has one). For each point:

- per axis the range is exact: e_x in +-(sum_k c_k |G_k[x]| + sum_i tol_i |J[x, i]|) (a
  linear function over a product of discs and intervals);
- `ascent`: the largest |e| found by coordinate ascents, started from the STARTS sampled
  states of largest first-order |e| (so never below the sampled first-order maximum):
  seat by seat the best direction (a grid of ANGLES angles, then Newton steps on the
  angle, kept only where they gain), each tolerance term at its better end, sweep after
  sweep over all of them; a point whose sweep gains less than STOP relative stops (at
  most SWEEPS sweeps). Every step keeps or raises |e|: each ascent ends at a local
  maximum, a lower bound of the true largest first-order |e|; the best is kept. (On the
  kr1000titan's 200 study points, benchmarks/bench_sweep_worst.py, one start left 8
  points up to 7.7 % under the 8-random-start ascent of benchmarks/study_sweep_samples.py,
  4 starts 2 points, 8 starts none, with a 256-angle grid; 32 angles, 2 Newton steps,
  STOP 1e-8 and 30 sweeps reach it too, no point more than 1e-6 under it, in 0.55 of the time);
- `outer`: sum_k c_k sigma_max(G_k) + sum_i tol_i |J_i| (triangle inequality), an upper
  bound of it. The true (first-order) worst case lies in [ascent, outer].

Every operation is batched over the points of a chunk (no loop over points); the loops run
over seats and sweeps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from torchcal.errors import InputError
from torchcal.reliability.uncertainty import ClearanceModel, deviation_map, sample_states

__all__ = ["BOUNDS", "check_bounds", "ClearanceSet", "clearance_set", "worst_extremes"]

#: the `bounds` of a sweep: "sampled" (the paper's: extremes over the M sampled states) or
#: "worst" (extremes over the whole clearance set, this module)
BOUNDS = ("sampled", "worst")
ANGLES = 32  # grid of seat directions per coordinate step (11.25 degrees), refined by Newton
NEWTON = 2  # Newton steps on the angle after the grid
STARTS = 8  # ascents per point, from its STARTS sampled states of largest first-order |e|
SWEEPS = 30  # most sweeps over the coordinates
STOP = 1e-8  # a point whose sweep gains less than this relative (|e|^2) stops (the ascent ends when all have)


def check_bounds(bounds) -> str:
    """`bounds` if it is one of BOUNDS, else one InputError."""
    if bounds not in BOUNDS:
        raise InputError(f"bounds must be one of {', '.join(BOUNDS)}, got {bounds!r}")
    return bounds


@dataclass(frozen=True)
class ClearanceSet:
    """The clearance set a sweep's M states were drawn from, in seat coordinates (float64 CPU).

    Attributes:
        dmap: (5n, 4n) the deviation map D (`deviation_map`): deviations = D @ seat offsets.
        clearance: (2n,) mm c_k, seat k's largest offset.
        tolerance: (5n,) half-widths of the tolerance box (rad, mm), or None.
        states: (M, 4n) the sampled seat offsets (mm), flattened as D's columns.
        residual: (M, 5n) the sampled tolerance deviations (zero without a box).
    """

    dmap: torch.Tensor
    clearance: torch.Tensor
    tolerance: torch.Tensor | None
    states: torch.Tensor
    residual: torch.Tensor


def clearance_set(robot, model: ClearanceModel, deviations: torch.Tensor, seed: int) -> ClearanceSet:
    """The `ClearanceSet` of the sweep states `deviations` (M, n, 5) drawn from `model` with
    `seed` (`torchcal.reliability.sweep.sweep_states`: the seat offsets are its generator's
    first draw, redrawn here). One InputError where the deviations are not those states."""
    M = deviations.shape[0]
    dmap = deviation_map(robot, model)
    states = sample_states(model, int(M), torch.Generator().manual_seed(int(seed))).reshape(M, -1)
    dev = deviations.detach().to("cpu", torch.float64).reshape(M, -1)
    residual = dev - states @ dmap.T
    tol = None if model.tolerance is None else torch.tensor(model.tolerance, dtype=torch.float64).reshape(-1)
    limit = torch.zeros(dev.shape[1], dtype=torch.float64) if tol is None else tol
    if not bool((residual.abs() <= limit + 1e-9 * (1.0 + dev.abs().amax())).all()):
        raise InputError("bounds='worst': the deviation sets are not the clearance states of the model drawn with "
                         "this seed; sweep with the model (no deviations of your own) or with bounds='sampled'")
    return ClearanceSet(dmap=dmap, clearance=torch.tensor(model.clearance_mm, dtype=torch.float64),
                        tolerance=tol, states=states, residual=residual)


def _seat_value(w, H, c, phi):
    """g(phi) = 2 c w.v + c^2 v^T H v and its first two derivatives, v = (cos, sin) phi.
    w (N, 2), H (N, 3) [H00, H01, H11], phi (N,) -> three (N,)."""
    cs, sn = torch.cos(phi), torch.sin(phi)
    c2, s2 = torch.cos(2 * phi), torch.sin(2 * phi)
    half = (H[:, 0] - H[:, 2]) / 2
    lin = 2 * c * (w[:, 0] * cs + w[:, 1] * sn)
    g = lin + c * c * ((H[:, 0] + H[:, 2]) / 2 + half * c2 + H[:, 1] * s2)
    d1 = 2 * c * (-w[:, 0] * sn + w[:, 1] * cs) + c * c * 2 * (-half * s2 + H[:, 1] * c2)
    d2 = -lin + c * c * 4 * (-half * c2 - H[:, 1] * s2)
    return g, d1, d2


def _best_direction(w, H, c, grid):
    """The angle (N,) maximising g (`_seat_value`) over the circle: the best of the grid
    (basis (5, A)), then NEWTON Newton steps, each kept only where it gains."""
    feats = torch.stack([w[:, 0], w[:, 1], H[:, 0], H[:, 1], H[:, 2]], dim=1)  # (N, 5)
    basis, phis = grid
    phi = phis[(feats @ (basis * basis.new_tensor([2 * c, 2 * c, c * c, c * c, c * c])[:, None])).argmax(1)]
    g, d1, d2 = _seat_value(w, H, c, phi)
    for _ in range(NEWTON):
        step = torch.where(d2 < 0, -d1 / d2.clamp_max(-1e-300), torch.zeros_like(d1))
        cand = phi + step.clamp(-0.1, 0.1)
        gc, c1, c2 = _seat_value(w, H, c, cand)
        better = gc > g
        phi, g = torch.where(better, cand, phi), torch.where(better, gc, g)
        d1, d2 = torch.where(better, c1, d1), torch.where(better, c2, d2)
    return phi, g


def _grid(dtype, device):
    phi = torch.arange(ANGLES, dtype=dtype, device=device) * (2 * math.pi / ANGLES)
    cs, sn = torch.cos(phi), torch.sin(phi)
    return torch.stack([cs, sn, cs * cs, 2 * cs * sn, sn * sn]), phi  # (5, A) features of g / (c factors)


def worst_extremes(J: torch.Tensor, deviations: torch.Tensor, cs: ClearanceSet):
    """First-order extremes of the error over the clearance set at N points (module doc).

    J (N, 3, 5n) mm per unit deviation (`torchcal.kinematics.mdh.param_jacobian`, world
    frame), deviations (M, n, 5) the sampled states (the ascents start from the STARTS of
    largest first-order |e| at each point), cs their `ClearanceSet`. Returns axis (N, 3) mm
    (the exact range is +-axis), ascent (N,) mm and outer (N,) mm, ascent <= outer.
    """
    N, dt, dev_ = J.shape[0], J.dtype, J.device
    D = cs.dmap.to(dev_, dt)
    c = cs.clearance.to(dev_, dt)
    G = (J @ D).reshape(N, 3, -1, 2)  # (N, 3, 2n, 2)
    seats = [k for k in range(c.shape[0]) if float(c[k]) > 0]
    # exact axis range and the triangle-inequality bound of |e|
    axis = (G.norm(dim=-1) * c).sum(-1)  # (N, 3)
    Hs = {}
    outer = torch.zeros(N, dtype=dt, device=dev_)
    for k in seats:
        Gk = G[:, :, k]  # (N, 3, 2)
        h = torch.stack([(Gk[..., 0] * Gk[..., 0]).sum(1), (Gk[..., 0] * Gk[..., 1]).sum(1),
                         (Gk[..., 1] * Gk[..., 1]).sum(1)], dim=1)  # (N, 3): H00, H01, H11
        Hs[k] = h
        lam = (h[:, 0] + h[:, 2]) / 2 + torch.sqrt(((h[:, 0] - h[:, 2]) / 2) ** 2 + h[:, 1] ** 2)
        outer = outer + c[k] * lam.clamp_min(0).sqrt()
    tol = None if cs.tolerance is None else cs.tolerance.to(dev_, dt)
    terms = [] if tol is None else [i for i in range(tol.shape[0]) if float(tol[i]) > 0]
    if terms:
        axis = axis + (J.abs() * tol).sum(-1)
        outer = outer + (J.norm(dim=1) * tol).sum(-1)
    # start: the sampled state of largest first-order |e| per point
    flat = deviations.to(dev_, dt).reshape(deviations.shape[0], -1)  # (M, 5n)
    e_all = torch.einsum("nij,mj->nmi", J, flat)  # (N, M, 3)
    S = min(STARTS, flat.shape[0])
    best = e_all.square().sum(-1).topk(S, dim=1).indices.reshape(-1)  # (N S,): rows point-major
    N0, N = N, N * S
    G, J = G.repeat_interleave(S, 0), J.repeat_interleave(S, 0)
    Hs = {k: h.repeat_interleave(S, 0) for k, h in Hs.items()}
    u = cs.states.to(dev_, dt)[best].reshape(N, -1, 2).clone()  # (N S, 2n, 2)
    t = cs.residual.to(dev_, dt)[best].clone()  # (N S, 5n)
    e = torch.einsum("nikc,nkc->ni", G, u) + torch.einsum("nij,nj->ni", J, t)  # (N, 3)
    grid = _grid(dt, dev_)
    ascent = torch.empty(N, dtype=dt, device=dev_)
    idx = torch.arange(N, device=dev_)  # the points still gaining, whose tensors follow
    H = dict(Hs)
    for _ in range(SWEEPS):
        before = e.square().sum(1)
        for k in seats:
            Gk = G[:, :, k]
            r = e - (Gk @ u[:, k, :, None])[..., 0]  # the error without seat k
            w = (Gk * r[..., None]).sum(1)  # (N, 2) G_k^T r
            phi, g = _best_direction(w, H[k], float(c[k]), grid)
            cur = (2 * w * u[:, k]).sum(1) + (Gk @ u[:, k, :, None])[..., 0].square().sum(1)
            new = c[k] * torch.stack([torch.cos(phi), torch.sin(phi)], 1)
            u[:, k] = torch.where((g > cur)[:, None], new, u[:, k])
            e = r + (Gk @ u[:, k, :, None])[..., 0]
        for i in terms:
            r = e - J[:, :, i] * t[:, i:i + 1]
            side = torch.where((r * J[:, :, i]).sum(1) >= 0, tol[i], -tol[i])
            t[:, i] = side
            e = r + J[:, :, i] * side[:, None]
        after = e.square().sum(1)
        ascent[idx] = after.sqrt()
        going = (after - before) > STOP * after.clamp_min(1e-300)
        n_going = int(going.sum())
        if n_going == 0:
            break
        if 2 * n_going <= idx.shape[0]:  # drop the points that stopped gaining (every other time at most)
            idx, G, J, u, t, e = idx[going], G[going], J[going], u[going], t[going], e[going]
            H = {k: h[going] for k, h in H.items()}
    return axis, ascent.reshape(N0, S).amax(1), outer
