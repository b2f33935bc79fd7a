"""Optimal measurement poses: pick N of M candidate poses for a `CalibrationModel`.

The information of a plan S is ``M(S) = sum_{i in S} J_i^T J_i`` over the 3 x K position
Jacobians of the identifiable parameters (at nominal, columns scaled to unit norm over the
candidates so mm and rad columns weigh alike). Criteria (larger is better):

- ``D``: log det M (D-optimality, as FIGAROH uses on the base regressor);
- ``O1``: Borm & Menq's O1 = (prod s_k)^(1/K) / sqrt(N) of the scaled Jacobian: for fixed N
  a monotone function of det M, so it picks the same poses as D (reported as O1);
- ``E``: the smallest eigenvalue of M (the worst-determined direction).

Selection is greedy (each step adds the candidate with the largest gain: for D,
``log det(I_3 + J_c M^-1 J_c^T)`` batched over all candidates; for E, the exact smallest
eigenvalue among the 256 candidates with the largest D gain), started from a small ridge,
then exchange passes (Fedorov): swap a chosen pose for a candidate while the criterion grows.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchcal.calibration.identifiability import identifiability
from torchcal.calibration.model import CalibrationModel
from torchcal.effects import make_context
from torchcal.errors import InputError

CRITERIA = ("D", "O1", "E")


def candidate_jacobian(model: CalibrationModel, q: torch.Tensor, payload_kg=None, temp_c=None):
    """(M, 3, P) position Jacobian at nominal parameters for candidates q (M, n) rad.
    Geometric-only models use the analytic `Robot.param_jacobian` (faster)."""
    if not model.effects:
        return model.robot.param_jacobian(q)
    ctx = make_context(model.robot, q, payload_kg, temp_c)
    return model.jacobian(model.zeros(), ctx)


def scaled_columns(J: torch.Tensor, model: CalibrationModel):
    """(free (P,) bool identifiable at the candidates, A (M, 3, K) unit-norm columns).

    The gauge is the fit's (`torchcal.calibration.fit`): of a frame (base frame, tool
    offset) and the robot deviations it cannot be told apart from, the frame is kept and
    the deviation held, so the held parameters are those the fit of the measured plan holds."""
    from torchcal.calibration.plausibility import plausible_scales

    first = ~torch.isfinite(plausible_scales(model))
    rep = identifiability(J, model.param_names(), model.default_free(), first=first)
    A = J[:, :, rep.free]
    A = A / A.reshape(-1, A.shape[-1]).norm(dim=0).clamp_min(1e-300)
    return rep.free, A


def criterion(A: torch.Tensor, kind: str) -> float:
    """Value of criterion `kind` for a plan with Jacobian blocks A (N, 3, K)."""
    N, _, K = A.shape
    info = A.reshape(-1, K).T @ A.reshape(-1, K)
    ev = torch.linalg.eigvalsh(info).clamp_min(1e-300)
    if kind == "D":
        return float(ev.log().sum())
    if kind == "O1":
        return float(torch.exp(0.5 * ev.log().mean()) / N ** 0.5)
    if kind == "E":
        return float(ev[0])
    raise InputError(f"criterion: unknown {kind!r}; expected one of {', '.join(CRITERIA)}")


def _gains_d(A, Minv):
    """log det(I + A_c Minv A_c^T) for every candidate: A (M, 3, K) -> (M,)."""
    S = A @ Minv @ A.transpose(1, 2)
    return torch.linalg.slogdet(torch.eye(3, dtype=A.dtype) + S)[1]


def _step(A, info, kind, taken):
    Minv = torch.linalg.inv(info)
    g = _gains_d(A, Minv)
    g[taken] = -torch.inf
    if kind != "E":
        return int(g.argmax())
    short = torch.topk(g, min(256, int(torch.isfinite(g).sum()))).indices
    Ms = info + A[short].transpose(1, 2) @ A[short]
    return int(short[torch.linalg.eigvalsh(Ms)[:, 0].argmax()])


@dataclass
class Plan:
    """index: (N,) chosen candidate indices; history: criterion after each greedy step
    (k = 1..N, ridge-regularised below full rank); value: final criterion."""

    index: torch.Tensor
    history: list
    value: float


def select(A: torch.Tensor, n: int, kind: str = "D", exchange_passes: int = 2) -> Plan:
    """Greedy + exchange selection of n of the M candidates, A (M, 3, K) scaled blocks."""
    kind = kind.upper()
    if kind not in CRITERIA:
        raise InputError(f"criterion: unknown {kind!r}; expected one of {', '.join(CRITERIA)}")
    M, _, K = A.shape
    if n > M:
        raise InputError(f"n: {n} poses is more than the {M} candidates")
    G = A.transpose(1, 2) @ A  # (M, K, K)
    ridge = 1e-6 * float(G.sum(0).trace()) / M / K * torch.eye(K, dtype=A.dtype)
    info = ridge.clone()
    taken = torch.zeros(M, dtype=torch.bool)
    chosen, history = [], []
    for _ in range(n):
        c = _step(A, info, kind, taken)
        chosen.append(c)
        taken[c] = True
        info = info + G[c]
        history.append(criterion(A[chosen], kind) if 3 * len(chosen) >= K else None)
    best = criterion(A[chosen], kind)
    for _ in range(exchange_passes):  # Fedorov-style: drop one, add the best, keep if better
        improved = False
        for pos in range(n):
            out = chosen[pos]
            info_minus = ridge + G[[c for k, c in enumerate(chosen) if k != pos]].sum(0)
            taken[out] = False
            c = _step(A, info_minus, kind, taken)
            trial = chosen[:pos] + [c] + chosen[pos + 1:]
            v = criterion(A[trial], kind)
            if c != out and v > best + 1e-12 * abs(best):
                chosen, best, improved = trial, v, True
                taken[c] = True
            else:
                taken[out] = True
        if not improved:
            break
    return Plan(torch.tensor(chosen), history, best)


def observability(J: torch.Tensor, model: CalibrationModel, free: torch.Tensor) -> dict:
    """O1..O5 of a plan's Jacobian J (N, 3, P) for the identifiable parameters `free`."""
    return identifiability(J, model.param_names(), free).observability
