"""Identifiability of the fit's parameters (at the starting point, on the column-scaled
Jacobian).

- Column pivoting orders the free parameters from most to least independent; those whose
  pivot falls below ``rank_tol`` (unit columns) cannot be identified from these poses.
  They are reported by name and *held at nominal* (zero deviation) instead of being
  silently damped as eq. 29 would. This is what removes the gauge (a base frame against
  joint 1's dtheta and dd, a tool offset against the last link): the columns in `first`
  (the fit passes the parameters without a plausibility prior, the frames) are pivoted
  first, so the robot's deviation is the one held.
- `recheck`: from a cold start the fit judges once more at its first solution; the free
  parameters stay, a held one is freed only where its pivot reaches `RECHECK_TOL` (a far
  start can make parameters look dependent that are not; small deviations only break an
  exact symmetry of the nominal geometry to their own order).
- `check_enough_rows`: fewer equations than identifiable parameters is refused in words,
  with the number of poses the model needs (`generic_rank` at random poses).
- Singular values of the identifiable columns give the condition number and the
  observability indices of Borm & Menq / Nahvi & Hollerbach (O1..O5, m = number of poses).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from torchcal.errors import DataError, InputError

RANK_TOL = 1e-6
#: every candidate counts as identifiable, without the pivoting, when the smallest singular
#: value of the unit columns is at least this many rank_tol (`beyond_doubt`)
SAFE_RANK = 10.0
RECHECK_TOL = 1e-2  # pivot a parameter held at a cold start needs at the first solution


@dataclass
class Identifiability:
    """Rank analysis of the scaled Jacobian.

    free: (P,) bool identifiable parameters; held: names held at nominal; rank: number
    identifiable; condition: condition number of the scaled identifiable columns;
    observability: dict O1..O5.
    """

    free: torch.Tensor
    held: list[str]
    rank: int
    condition: float
    observability: dict
    n_rows: int

    def to_dict(self) -> dict:
        return {"rank": self.rank, "condition_number": self.condition, "held_at_nominal": self.held,
                "observability": self.observability, "poses": self.n_rows}


def _pivoted(U: torch.Tensor, Q: torch.Tensor, rank_tol: float) -> list[int]:
    """Indices of the rows of U (p, R) (unit vectors: the columns of the scaled Jacobian)
    kept, in pivot order, by Gram-Schmidt with pivoting of U projected off the orthonormal
    rows of Q (k, R): at each step the row with the largest remaining norm (the lowest
    index among those equal to rounding, so that exactly dependent columns of a symmetric
    geometry are chosen the same way whatever the last digits of the data), while that
    norm exceeds rank_tol."""
    P = U - (U @ Q.T) @ Q if Q.shape[0] else U.clone()
    kept: list[int] = []
    taken = torch.zeros(P.shape[0], dtype=torch.bool, device=P.device)
    for _ in range(P.shape[0]):
        norms = torch.linalg.vector_norm(P, dim=1).masked_fill_(taken, -1.0)
        best = float(norms.max())
        if best <= rank_tol:
            break
        i = int(torch.nonzero(norms >= best * (1 - 1e-9))[0])
        q = P[i] / norms[i]
        P.addr_(P @ q, q, alpha=-1.0)
        P.addr_(P @ q, q, alpha=-1.0)  # twice is enough (Kahan): orthogonal to rounding
        kept.append(i)
        taken[i] = True
    return kept


def identifiability(J: torch.Tensor, names, candidate_free, rank_tol: float = RANK_TOL,
                    first=None, rest_tol: float | None = None) -> Identifiability:
    """J (N, 3, P) or (R, P) position Jacobian; candidate_free (P,) bool.

    first: (P,) bool, columns chosen before the others (the gauge: of a base frame and
    joint 1's dtheta / dd, or a tool offset and the last link's length, the ones in
    `first` are kept and the others held). The fit passes the parameters without a
    plausibility prior (frames), so the prior falls on a robot deviation only where
    the data determine it. rest_tol: the pivot threshold of the columns not in `first`
    (default rank_tol). Computed in float64 on J's device."""
    n_rows = J.shape[0]
    J = J.detach().reshape(-1, J.shape[-1]).to(torch.float64)
    dev = J.device
    cand = torch.nonzero(candidate_free.to(dev)).flatten()
    norms = torch.linalg.vector_norm(J[:, cand], dim=0)
    live = cand[norms > 1e-12 * max(float(norms.max()) if norms.numel() else 0.0, 1e-300)]
    # unit columns, rounded to 1e-10: columns equal in exact arithmetic (dd of parallel
    # axes, base_rz and dtheta1) become equal in floating point too, and a norm larger by
    # at most 1e-8 for earlier columns makes the pivoting keep the first of them (the
    # robot's before the base frame's), whatever the rounding of the Jacobian
    U = torch.round(J[:, live].T / torch.linalg.vector_norm(J[:, live], dim=0)[:, None], decimals=10)
    n_live = live.numel()
    U = U * (1 + 1e-8 * torch.arange(n_live, 0, -1, dtype=J.dtype, device=dev) / max(n_live, 1))[:, None]
    if U.shape[1] > n_live:
        # the triangular factor of U^T has the same column norms, projections and singular
        # values (an orthogonal map keeps inner products): the pivoting runs on (L, L)
        # instead of (L, rows)
        U = torch.linalg.qr(U.T, mode="r").R.T.contiguous()
    free = torch.zeros(J.shape[1], dtype=torch.bool)
    if n_live:  # U (n_live, R): the unit columns as rows, each one contiguous
        pri = torch.zeros(n_live, dtype=torch.bool, device=dev) if first is None else first.to(dev)[live]
        a = torch.nonzero(pri).flatten()[_pivoted(U[pri], U.new_zeros(0, U.shape[1]), rank_tol)]
        Qa = torch.linalg.qr(U[a].T).Q.T if a.numel() else U.new_zeros(0, U.shape[1])
        b = torch.nonzero(~pri).flatten()[_pivoted(U[~pri], Qa, rank_tol if rest_tol is None else rest_tol)]
        kept = torch.cat([a, b]).sort().values
        rank = kept.numel()
        free[live[kept].cpu()] = True
        s = torch.linalg.svdvals(U[kept]).cpu()
    else:
        rank, s = 0, torch.ones(1, dtype=torch.float64)
    held = [names[i] for i in cand.tolist() if not free[i]]
    return Identifiability(free, held, rank, float(s[0] / s[-1]), observability(s, n_rows), n_rows)


MIN_EQUATIONS_PER_PARAM = 2  # fewer: a least-squares fit's error on new poses exceeds its noise by sqrt(2) or more


class FewEquationsWarning(UserWarning):
    """A fit of fewer than MIN_EQUATIONS_PER_PARAM equations of distinct poses per identified
    parameter: its rms understates its error on new poses."""


def few_equations(report: Identifiability, m) -> str | None:
    """None, or one line when the distinct poses (and reflectors) of the measurements `m`
    give fewer than MIN_EQUATIONS_PER_PARAM equations (3 per position, 6 with rx, ry, rz)
    per parameter `report` identifies; repeats of a pose add no equation about the
    geometry. With n equations and p parameters a least-squares fit predicts a new pose
    with an error variance of about sigma^2 (1 + p / (n - p - 1)), while its own residuals
    shrink to sigma^2 (1 - p / n): a ur5e fitted with joint_compliance:2,3 and
    gear_periodic:2,3 on 20 poses (51 parameters, 60 equations) printed rms 0.0178 mm and
    erred by 0.112 mm on 200 new poses."""
    free = int(report.free.sum())
    per_row = 3 if m.rxyz is None else 6
    keys = m.pose if m.point is None else torch.stack([m.pose, m.point], -1)
    n_poses = int(torch.unique(keys, dim=0).shape[0])
    n = per_row * n_poses
    if free == 0 or n >= MIN_EQUATIONS_PER_PARAM * free:
        return None
    what = m.source or "data"
    grow = math.sqrt(1 + free / max(n - free - 1, 1))
    need = math.ceil(MIN_EQUATIONS_PER_PARAM * free / per_row)
    repeats = f" ({len(m)} rows; repeats of a pose add none)" if n_poses < len(m) else ""
    return (f"{what}: {n_poses} distinct poses give {n} equations{repeats} for {free} identified parameters, fewer "
            f"than {MIN_EQUATIONS_PER_PARAM} per parameter: the fit's rms understates its error on new poses (by "
            f"{grow:.2g}x for the noise alone); measure at least {need} poses, or fit fewer effects")


def unidentified_effects(model, held) -> list[str]:
    """Specs of `model`'s effects none of whose parameters is identifiable: every one of
    its parameter names in `held` (an `Identifiability.held`). Such an effect changes no
    prediction, so naming it as fitted physics claims what the data cannot tell."""
    held = set(held)
    return [e.spec() for e in model.effects if e.param_names() and set(e.param_names()) <= held]


def unidentified_reason(effect, m) -> str:
    """Why the measurements `m` can identify none of `effect`'s parameters, in words, from
    what it reads that never varies: a temperature (uses_temperature) or payload
    (uses_payload) the same on every row, its joints never moving; "" when none of these."""
    out = []
    for column, unit, used in (("temp_c", "degC", effect.uses_temperature),
                               ("payload_kg", "kg", effect.uses_payload)):
        v = getattr(m, column)
        if used and v is not None and v.numel() and float(v.max() - v.min()) < 1e-9:
            out.append(f"{column} is {float(v[0]):.6g} {unit} on every row")
    joints = getattr(effect, "joints", None) or []
    still = [j for j in joints if float(m.q[:, j - 1].max() - m.q[:, j - 1].min()) < 1e-12]
    if still and len(still) == len(joints):
        out.append(f"{', '.join(f'q{j}' for j in still)} never move{'s' if len(still) == 1 else ''}")
    return "; ".join(out)


def unidentified_lines(model, held, m) -> list[str]:
    """One line per effect of `model` none of whose parameters the measurements `m`
    identify (`unidentified_effects` of `held`): it changes nothing; why, where the rows
    say (`unidentified_reason`). What `fit` and `calibrate` print."""
    by_spec = {e.spec(): e for e in model.effects}
    out = []
    for spec in unidentified_effects(model, held):
        why = unidentified_reason(by_spec[spec], m)
        out.append(f"{spec}: none of its parameters is identifiable from these data (all held at nominal"
                   f"{': ' + why if why else ''}): it changes nothing")
    return out


def beyond_doubt(G: torch.Tensor, cand: torch.Tensor, n_rows: int,
                 rank_tol: float = RANK_TOL) -> Identifiability | None:
    """The `identifiability` report of rows whose Jacobian has the Gram matrix G (C, C) on
    the candidate columns cand (P,) bool, when every candidate is identifiable beyond
    doubt: no column below `identifiability`'s live threshold and the smallest singular
    value of the unit columns at least SAFE_RANK x rank_tol, so that no pivot of
    `identifiability` can fall to its threshold (a column's distance from the span of the
    others is at least that value; its rounding of the unit columns to 1e-10 and its
    1e-8 tie-breaking scale move singular values far less). Then free = cand, held none
    (what `identifiability` gives), and the condition and observability from the same
    singular values (to rounding, not bit for bit). None otherwise: the caller runs
    `identifiability` itself. An eigendecomposition of G (C, C) instead of a QR of the rows
    and the pivoting: for refits whose report serves its free set."""
    d = G.diagonal().clamp_min(0).sqrt()
    if not d.numel() or bool((d <= 1e-12 * d.max()).any()):
        return None
    s = torch.linalg.eigvalsh(G / d[:, None] / d[None]).flip(0).clamp_min(0).sqrt()
    if float(s[-1]) < SAFE_RANK * rank_tol:
        return None
    return Identifiability(cand.clone().cpu(), [], int(cand.sum()), float(s[0] / s[-1]),
                           observability(s.cpu(), n_rows), n_rows)


def observability(s: torch.Tensor, n_rows: int) -> dict:
    """O1..O5 of the singular values s (descending, > 0) of the scaled identifiable
    columns of a Jacobian of n_rows poses."""
    m = max(n_rows, 1)
    return {
        "O1": float(s.log().mean().exp() / math.sqrt(m)),
        "O2": float(s[-1] / s[0]),
        "O3": float(s[-1]),
        "O4": float(s[-1] ** 2 / s[0]),
        "O5": float(1.0 / (1.0 / s).sum()),
    }


def generic_rank(model, ctx, cand, rank_tol: float = RANK_TOL) -> int:
    """Number of parameters identifiable at random poses inside the joint limits (the
    data's payload / temperature values reused in turn): what enough poses would give."""
    from torchcal.effects import make_context
    from torchcal.robots.poses import random_poses

    robot = model.robot
    n = int(cand.sum()) + 16
    q = random_poses(robot, n, torch.Generator().manual_seed(0)).to(ctx.q)
    idx = torch.arange(n, device=ctx.q.device) % ctx.q.shape[0]
    temp = None if ctx.temp_c is None else ctx.temp_c[idx]
    payload = None if ctx.payload_kg is None else ctx.payload_kg[idx]
    g = make_context(robot, q, payload, temp)
    J = model.jacobian(model.zeros(), g)
    return identifiability(J, model.param_names(), cand, rank_tol).rank


def recheck(J: torch.Tensor, names, candidate_free, free_now: torch.Tensor,
            rank_tol: float = RANK_TOL) -> Identifiability:
    """Identifiability at a first solution (module doc): J (N, k, P) there; the parameters
    `free_now` (P,) bool stay free, a held one is freed where its pivot reaches RECHECK_TOL."""
    return identifiability(J, names, candidate_free, rank_tol, first=free_now, rest_tol=RECHECK_TOL)


def check_enough_rows(report: Identifiability, n_equations: float, model, ctx, cand, rank_tol: float = RANK_TOL) -> None:
    """InputError when `n_equations` (rows x residuals per row) do not exceed the rank of
    `report` (the equations, not the model, bound it: the message counts the parameters
    identifiable at generic poses, seeded, so it is reproducible), or when no candidate
    parameter (cand (P,) bool) is identifiable."""
    n_cand, n_rows = int(cand.sum()), report.n_rows
    if n_equations <= report.rank:
        kk = generic_rank(model, ctx, cand, rank_tol)
        need = kk // 3 + 1
        raise DataError(f"too few poses: {n_rows} poses give {3 * n_rows} equations (3 per pose) "
                         f"but the model [{', '.join(model.specs()) or 'geometric only'}] has {kk} "
                         f"identifiable parameters (of {n_cand}); need at least {need} poses, "
                         f"in practice {max(2 * need, need + 10)} or more spread over the workspace")
    if n_cand and report.rank == 0:
        raise DataError("no parameter is identifiable from these poses")
