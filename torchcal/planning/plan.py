"""``torchcal plan``: choose N measurement poses from M workspace candidates that best
determine the identifiable parameters of the model to be fitted, ordered so that the joint
moves stay short, and compare the plan with random plans of the same size.

The candidates are a Latin hypercube inside the joint limits filtered like the sweep's
workspace (`torchcal.robots.workspace.sample_workspace`); the criterion (D, O1 or E) is that
of `torchcal.planning.design` on the scaled parameter Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchcal.errors import InputError

__all__ = ["MeasurementPlan", "plan"]

OBSERVABILITY = ("O1", "O2", "O3", "O4", "O5")


@dataclass
class MeasurementPlan:
    """A chosen set of measurement poses.

    Attributes:
        q: (N, n) rad planned poses in measuring order.
        q_selected: (N, n) rad the same poses in selection order.
        candidates: (M, n) rad candidate poses.
        criterion, value: the design criterion and its value for the plan.
        history: criterion after each greedy step k = 1..N.
        random_values: criterion of each random plan of N candidates.
        observability: {"O1".."O5": value} of the plan; random_observability: one such dict per
            random plan.
        n_identifiable: identifiable parameters K; held: names of the parameters no
            candidate pose tells from those kept (held at nominal; the fit's gauge, so the
            fit of the measured plan holds the same).
        robot, effects: the robot's name and the model's effect specs.
        A: (M, 3, K) scaled candidate blocks; seed: the seed of the candidates (the random
            plans draw on seed + 1, and `random_curve` continues after them).
    """

    q: torch.Tensor
    q_selected: torch.Tensor
    candidates: torch.Tensor
    criterion: str
    value: float
    history: list
    random_values: torch.Tensor
    observability: dict
    random_observability: list
    n_identifiable: int
    held: list
    robot: str
    effects: list
    A: torch.Tensor
    seed: int

    def travel_deg(self, ordered: bool = True) -> float:
        """Sum of the largest joint move per step from home (all joints 0), deg: the measuring
        order (`ordered`) or the selection order."""
        from torchcal.planning.order import path_length

        q = self.q if ordered else self.q_selected
        return path_length(q, torch.zeros(q.shape[1], dtype=q.dtype)) * 57.29577951308232

    def random_curve(self, reps: int = 5) -> list:
        """Mean criterion of `reps` random plans of k candidates for k = 1..N (None where 3k
        equations cannot determine the identifiable parameters); continues the random plans' draws."""
        M, out = self.A.shape[0], []
        gen = _random_plans(M, self.q.shape[0], self.random_values.numel(), self.seed)[1]
        for k in range(1, self.q.shape[0] + 1):
            if 3 * k < self.n_identifiable:
                out.append(None)
                continue
            from torchcal.planning.design import criterion

            vals = [criterion(self.A[torch.randperm(M, generator=gen)[:k]], self.criterion)
                    for _ in range(reps)]
            out.append(sum(vals) / len(vals))
        return out

    def to_dict(self) -> dict:
        rnd = torch.tensor([[o[k] for k in OBSERVABILITY] for o in self.random_observability], dtype=torch.float64)
        return {"robot": self.robot, "effects": list(self.effects), "n": int(self.q.shape[0]),
                "candidates": int(self.candidates.shape[0]), "identifiable": self.n_identifiable,
                "criterion": self.criterion, "value": self.value,
                "random": {"plans": int(self.random_values.numel()), "mean": float(self.random_values.mean()),
                           "best": float(self.random_values.max())},
                "observability": {k: {"plan": float(self.observability[k]), "random_mean": float(rnd[:, i].mean()),
                                      "random_min": float(rnd[:, i].min()), "random_max": float(rnd[:, i].max())}
                                  for i, k in enumerate(OBSERVABILITY)},
                "held": list(self.held), "travel_deg": {"ordered": self.travel_deg(True),
                                                        "selection": self.travel_deg(False)}}


def _random_plans(M: int, n: int, count: int, seed: int):
    """([count random plans of n of M indices], the generator after drawing them) from seed + 1."""
    gen = torch.Generator().manual_seed(seed + 1)
    return [torch.randperm(M, generator=gen)[:n] for _ in range(count)], gen


def plan(robot, effects=(), *, n: int, candidates: int = 10_000, criterion: str = "D", seed: int = 0,
         payload_kg: float | None = None, temp_c: float = 20.0, workspace=None,
         random_plans: int = 20) -> MeasurementPlan:
    """Choose n of `candidates` workspace poses for fitting `robot` (a preset name or a
    `Robot`) with `effects` (specs). criterion: "D", "O1" or "E"; seed: the candidates' and
    the random plans' seed (the random plans draw on seed + 1); payload_kg (default the rated
    payload) and temp_c: the conditions at which load and thermal effects are evaluated;
    workspace: a `torchcal.robots.workspace.Workspace` (default `Workspace()`); a temp_c or
    payload_kg that looks like another unit gets one `ConditionWarning` each. InputError
    when n exceeds the candidates or 3 n equations cannot determine the identifiable
    parameters."""
    from torchcal.calibration.model import CalibrationModel
    from torchcal.effects.spec import parse_specs
    from torchcal.planning import design
    from torchcal.planning.order import order_poses
    from torchcal.robots.workspace import sample_workspace
    from torchcal.robots.robot import preset

    from torchcal.measurements import check_conditions_given

    rob = preset(robot)
    check_conditions_given(temp_c, payload_kg, rob, "plan", stacklevel=2)  # kelvin, grams: one warning each
    specs = [str(s) for s in parse_specs(list(effects), rob.n)] if effects else []
    model = CalibrationModel(rob, specs)
    if n > candidates:
        raise InputError(f"n: {n} poses is more than the {candidates} candidates")
    q = sample_workspace(rob, candidates, seed=seed, workspace=workspace)
    M = q.shape[0]
    payload = torch.full((M,), rob.payload_kg if payload_kg is None else payload_kg, dtype=torch.float64)
    temp = torch.full((M,), temp_c, dtype=torch.float64)
    J = design.candidate_jacobian(model, q, payload, temp)
    free, A = design.scaled_columns(J, model)
    K = int(free.sum())
    if 3 * n < K:
        raise InputError(f"n: {n} poses give {3 * n} equations, which cannot determine the {K} identifiable "
                         f"parameters", fix=("n", str(-(-K // 3))))
    chosen = design.select(A, n, criterion)
    idx = chosen.index[order_poses(q[chosen.index])]
    rand = _random_plans(M, n, random_plans, seed)[0]
    crit_r = torch.tensor([design.criterion(A[r], criterion) for r in rand])
    held = [name for name, f, c in zip(model.param_names(), free.tolist(), model.default_free().tolist())
            if c and not f]
    return MeasurementPlan(q[idx], q[chosen.index], q, criterion, chosen.value, chosen.history, crit_r,
                           design.observability(J[idx], model, free),
                           [design.observability(J[r], model, free) for r in rand], K, held, rob.name, specs, A, seed)
