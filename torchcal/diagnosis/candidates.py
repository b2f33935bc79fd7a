"""The candidates of the diagnosis: which effects could be missing, and their columns.

- `candidate_specs`: the registry's effects (built-in and user) not in the model yet,
  joint effects one joint at a time, none whose data are missing;
- `all_candidate_columns`: d model / d candidate parameters at the fit, every candidate
  at once (each added at zero, where it is the identity);
- `random_clearance_basis`: the TCP displacement per mrad of random tilt of a joint's axis
  (the random part of joint_clearance, a variance term);
- `Candidate`: one candidate's pre-screen evidence.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from torchcal.calibration.model import CalibrationModel
from torchcal.effects import build
from torchcal.effects.spec import EFFECTS, format_spec
from torchcal.robots.robot import Robot

MRAD = 1e-3  # random-clearance tilts are fitted in mrad


@dataclass
class Candidate:
    """One candidate effect and its evidence.

    rms_mm: training distance RMS of the linearised refit with it; cv_rms_mm: held-out;
    cv_gain: relative held-out RMS gain; score: held-out log-likelihood gain, nats per
    pose (the ranking); p_value: F-test (deterministic part) or likelihood-ratio test
    (random part), whichever is smaller; k: new identifiable parameters; held_out_ll,
    held_out_sq: per-pose held-out log-likelihood and squared distance error;
    deterministic: significant by its deterministic part (else, if significant, by its
    random part only).
    """

    effect: str
    joints: tuple
    rms_mm: float
    cv_rms_mm: float
    score: float
    p_value: float
    k: int
    significant: bool = False
    cv_gain: float = 0.0
    held_out_ll: np.ndarray | None = field(default=None, repr=False)  # (poses,) nats
    held_out_sq: np.ndarray | None = field(default=None, repr=False)  # (poses,) mm^2
    deterministic: bool = False  # significant by its deterministic part (F-test + gain)
    orders: tuple = ()  # per joint, for an effect with orders (joint_periodic)

    @property
    def spec(self) -> str:
        return format_spec(self.effect, self.joints, self.orders)

    def to_dict(self) -> dict:
        return {"effect": self.effect, "joints": list(self.joints), "rms_mm": self.rms_mm,
                "cv_rms_mm": self.cv_rms_mm, "score": self.score, "significant": self.significant,
                "p_value": self.p_value, "new_parameters": self.k, "cv_gain": self.cv_gain,
                **({"orders": [list(ks) for ks in self.orders]} if self.orders else {})}



def candidate_specs(robot: Robot, present: dict, ctx) -> list[tuple[str, tuple]]:
    """Effects of the registry (built-in and user effects) not in the model yet; joint
    effects on each joint they do not cover yet; none whose data are missing or that
    refuse the robot or joint (building it or its `check_context` raises InputError, e.g.
    thermal_expansion without temp_c, gear_transmission without gear_ratio, axis_tilt:1)."""
    from torchcal.effects import lookup
    from torchcal.errors import InputError

    out = []
    for name, takes in EFFECTS.items():
        if name in present and not takes:
            continue
        joints = [(j,) for j in range(1, robot.n + 1) if j not in present.get(name, ())] if takes else [()]
        for js in joints:
            try:  # the data lack a column, or the effect does not exist there (axis_tilt:1)
                lookup(name)(robot, js).check_context(ctx)
            except InputError:
                continue
            out.append((name, js))
    return out


def spec_text(name, joints, orders=()):
    return format_spec(name, joints, orders)


def candidate_columns(robot, base_model: CalibrationModel, theta, ctx, spec: str) -> np.ndarray:
    """d model / d candidate parameters at theta (3N, k), the candidate's values at zero."""
    aug = CalibrationModel(robot, base_model.specs() + [spec], points=base_model.points or None)
    k = aug.n_params - base_model.n_params
    if k == 0:  # an effect with no parameters here (e.g. a user effect on joint 1): nothing to add
        return np.zeros((3 * ctx.n_rows, 0))

    C = aug.jacobian(torch.cat([theta, theta.new_zeros(k)]), ctx)[..., base_model.n_params:]
    return C.reshape(-1, k).numpy(force=True)


def all_candidate_columns(robot, base_model: CalibrationModel, theta, ctx, specs, orders=None) -> dict:
    """`candidate_columns` of every (name, joints) in specs, from one forward-mode pass: the
    candidates are added side by side as separate effects at zero, where each is the
    identity, so each one's columns are those of the model with it alone. `orders`:
    (name, joints) -> orders per joint, for effects with orders."""
    specs = list(specs)
    if not specs:
        return {}
    extra = [build(spec_text(n, j, (orders or {}).get((n, j), ())), robot) for n, j in specs]
    aug = CalibrationModel(robot, list(base_model.effects) + extra)
    k = aug.n_params - base_model.n_params

    C = aug.jacobian(torch.cat([theta, theta.new_zeros(k)]), ctx)[..., base_model.n_params:]
    C = C.reshape(-1, k).numpy(force=True)
    out, start = {}, 0
    for spec, e in zip(specs, extra):
        out[spec] = C[:, start:start + e.n_params]
        start += e.n_params
    return out


def random_clearance_basis(robot: Robot, ctx, xyz: torch.Tensor, joint: int) -> np.ndarray:
    """(N, 3, 2) TCP displacement in mm per mrad of random tilt of `joint`'s axis."""
    from torchcal.effects.joint_clearance import random_basis

    return (random_basis(ctx, joint, xyz) * MRAD).numpy(force=True)

