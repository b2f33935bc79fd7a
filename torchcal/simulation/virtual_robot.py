"""`VirtualRobot`: a simulated "real" robot that produces measurement files.

The real robot is the nominal one plus random geometric deviations of realistic size
plus chosen physical effects (the same effect modules a fitted model uses, with true
values), plus isotropic Gaussian measurement noise.

Sizes (defaults; all drawn from the robot's own seeded generator):

- geometric deviations: dtheta, dalpha, dbeta (declared joints only) ~ U(-0.02, 0.02) deg,
  dd, da ~ U(-0.5, 0.5) mm, all times `geometric_scale`;
- each effect is scaled so that its TCP displacement over the session has an RMS of
  `effect_mm` (0.3 mm: "realistic size, 0.1 to 1 mm at the TCP"); the direction of its
  parameter vector comes from physics where there is some (compliance: link masses and
  centers from the robot's reach, gravity torques; thermal: steel expansion) and is
  random otherwise (harmonic phases, backlash, scale, base and tool);
- joint_clearance: each listed axis can tilt up to t_max inside its bearing: for
  kr1000titan t_max = (c_1 + c_2) / L from docs/paper.md Table 2 (`torchcal.reliability.uncertainty`),
  the same from the "clearance" section of a robot file that has one, for other robots the
  tilt that moves the TCP by `effect_mm`. The load pushes the axis
  to one side by (1 - clearance_random) t_max (the deterministic part) and the rest,
  clearance_random t_max, is a random tilt per move, uniform in a disk perpendicular to
  the axis;
- a session with payload-dependent effects varies the payload per pose from 0 to the
  rated payload; one with thermal expansion drifts the temperature linearly from 20 to
  35 deg C over the session with 0.3 K of noise.

Measurement order with repeats: K cycles through the poses, each cycle in a seeded random
order, so repeated moves to a pose come from different predecessors (as a laser-tracker
session does); the robot starts at all-zero joints.
"""

from __future__ import annotations

import torch

from torchcal.effects import make_context
from torchcal.effects.joint_clearance import random_basis
from torchcal.effects.joint_compliance import JointCompliance
from torchcal.errors import InputError
from torchcal.measurements import Measurements
from torchcal.calibration.model import CalibrationModel
from torchcal.robots.poses import random_poses
from torchcal.robots.robot import Robot
from torchcal.effects.spec import parse_specs
from torchcal.reliability.uncertainty import ClearanceModel

GEOMETRIC_SIZE = (2e-2, 0.5, 0.5, 2e-2, 2e-2)  # dtheta deg, dd mm, da mm, dalpha deg, dbeta deg


def default_masses(robot: Robot):
    """Plausible link masses (n,) kg and centers (n, 3) mm in the link frames.

    Each link's center is half way back to the previous joint origin; masses scale with
    the rated payload (arm links about 1.5x, wrist links 0.1-0.3x the payload).
    """
    table = robot.table
    coms = torch.zeros(robot.n, 3, dtype=torch.float64)
    for k in range(robot.n):
        off, d, a, alpha, beta = table[k].tolist()
        # previous origin in frame k is -Ry(beta)^T Rx(alpha)^T (a, 0, d)
        ca, sa, cb, sb = map(float, (torch.cos(table[k, 3]), torch.sin(table[k, 3]),
                                     torch.cos(table[k, 4]), torch.sin(table[k, 4])))
        t = torch.tensor([a, sa * d, ca * d], dtype=torch.float64)  # Rx(alpha)^T (a, 0, d)
        t = torch.tensor([cb * t[0] - sb * t[2], t[1], sb * t[0] + cb * t[2]], dtype=torch.float64)
        coms[k] = -0.5 * t
    rel = torch.tensor([2.0, 1.5, 1.0, 0.3, 0.2, 0.1] + [0.1] * max(0, robot.n - 6), dtype=torch.float64)
    return max(robot.payload_kg, 1.0) * rel[: robot.n], coms


class VirtualRobot:
    """A simulated robot with hidden geometric deviations and physical effects.

    Args:
        robot: nominal robot.
        effects: effect specs ('joint_compliance:2,3', ...).
        seed: seed of every random draw (deviations, effect values, noise, order).
        geometric_scale: factor on the default geometric deviation sizes (0 = none).
        effect_mm: RMS TCP displacement of each effect over a reference session, mm; or a
            dict spec (or effect name) -> mm, one size per effect (0.3 mm where absent).
        clearance_random: share of the clearance tilt that is random per move.
        values: optional dict spec -> parameter tensor, replacing the drawn values.

    Attributes:
        model: the `CalibrationModel` whose `predict` is the real robot's mean behaviour.
        theta: (P,) its true parameters.
    """

    def __init__(self, robot: Robot, effects=(), seed: int = 0, geometric_scale: float = 1.0,
                 effect_mm: float = 0.3, clearance_random: float = 0.5, values=None):
        self.robot = robot
        self.specs = parse_specs(list(effects), robot.n) if effects else ()
        self.model = CalibrationModel(robot, [str(s) for s in self.specs])
        self.seed = seed
        self.gen = torch.Generator().manual_seed(seed)
        if not 0.0 <= clearance_random <= 1.0:
            raise InputError(f"clearance_random: expected a share in [0, 1], got {clearance_random}")
        self.clearance_random = clearance_random
        self.clearance_tilt_max = {}  # joint (1-based) -> largest tilt, rad
        self.theta = self._draw(geometric_scale, effect_mm, values or {})

    # -- what the session varies --------------------------------------------------------
    @property
    def uses_payload(self) -> bool:
        return any(e.uses_payload for e in self.model.effects)

    @property
    def uses_temperature(self) -> bool:
        return any(e.uses_temperature for e in self.model.effects)

    def _session(self, n_rows: int, pose_index: torch.Tensor, n_poses: int, gen):
        payload = temp = None
        if self.uses_payload:
            per_pose = torch.rand(n_poses, generator=gen, dtype=torch.float64) * self.robot.payload_kg
            payload = per_pose[pose_index]
        if self.uses_temperature:
            temp = 20.0 + 15.0 * torch.linspace(0, 1, n_rows, dtype=torch.float64) \
                + 0.3 * torch.randn(n_rows, generator=gen, dtype=torch.float64)
        return payload, temp

    # -- true values --------------------------------------------------------------------
    def _draw(self, geometric_scale, effect_mm, values) -> torch.Tensor:
        robot, model, gen = self.robot, self.model, self.gen
        theta = model.zeros()
        size = torch.tensor(GEOMETRIC_SIZE, dtype=torch.float64)
        size[[0, 3, 4]] = torch.deg2rad(size[[0, 3, 4]])
        geo = (2 * torch.rand(robot.n, 5, generator=gen, dtype=torch.float64) - 1) * size * geometric_scale
        geo[:, 4] *= robot.has_beta
        theta[model.slices[0]] = geo.reshape(-1)
        # a reference session to size the effects
        q = random_poses(robot, 200, gen)
        payload, temp = self._session(200, torch.arange(200), 200, gen)
        ctx = make_context(robot, q, payload, temp)
        for e, spec, sl in zip(model.effects, self.specs, model.slices[1:]):
            if str(spec) in values:
                theta[sl] = torch.as_tensor(values[str(spec)], dtype=torch.float64)
                continue
            if e.name == "joint_compliance":
                masses, coms = default_masses(robot)
                p = JointCompliance.params_from_physics(robot, e.joints, masses, coms,
                                                        torch.ones(robot.n, dtype=torch.float64))
            elif e.name == "thermal_expansion":
                p = torch.full((e.n_params,), 1.2e-5, dtype=torch.float64)
            elif e.name == "joint_clearance":
                p = torch.tensor([1.0, 0.02] * len(e.joints), dtype=torch.float64)  # tilt rad, shift mm
                if robot.clearance is not None or robot.name == "kr1000titan":  # the robot's clearance
                    # model (robot file "clearance" section; kr1000titan: docs/paper.md Table 2), physical size
                    cm = ClearanceModel.defaults(robot)
                    tilt, shift = cm.max_tilt_rad(), cm.max_shift_mm()
                    p = torch.stack([torch.stack([tilt[j - 1], shift[j - 1]]) for j in e.joints]).reshape(-1)
                    for j in e.joints:
                        self.clearance_tilt_max[j] = float(tilt[j - 1])
                    theta[sl] = p * (1 - self.clearance_random)
                    continue
            else:
                p = torch.randn(e.n_params, generator=gen, dtype=torch.float64)
                lo = e.lower_bounds()  # a physical sign (lost motion >= 0): the real robot has it too
                if lo is not None:
                    p = torch.where(torch.as_tensor(lo, dtype=torch.float64) >= 0, p.abs(), p)
            p = p * (1e-9 / p.abs().max().clamp_min(1e-300))  # probe in the linear range
            trial = theta.clone()
            trial[sl] = p
            disp = model.predict(trial, ctx) - model.predict(theta, ctx)
            rms = disp.norm(dim=-1).pow(2).mean().sqrt()
            if e.name == "thermal_expansion":  # steel is steel: keep its physical size
                p = torch.full((e.n_params,), 1.2e-5, dtype=torch.float64)
            else:
                p = p * (self._size_mm(effect_mm, spec) / rms.clamp_min(1e-300))
            if e.name == "joint_clearance":
                for i, j in enumerate(e.joints):
                    self.clearance_tilt_max[j] = float(p[2 * i].abs())
                p = p * (1 - self.clearance_random)
            theta[sl] = p
        return theta

    @staticmethod
    def _size_mm(effect_mm, spec) -> float:
        """TCP RMS of one effect: `effect_mm` itself, or its entry for the spec (by its
        full spec string, e.g. 'gear_periodic:2,3', or its name), 0.3 mm when absent."""
        if isinstance(effect_mm, dict):
            return float(effect_mm.get(str(spec), effect_mm.get(spec.name, 0.3)))
        return float(effect_mm)

    # -- measuring ----------------------------------------------------------------------
    def positions(self, q, payload_kg=None, temp_c=None, seed: torch.Generator | int | None = None) -> torch.Tensor:
        """True TCP positions (N, 3) mm for rows q (N, n) rad in movement order; with a
        seed (a torch.Generator or an int), the random clearance state per move is drawn
        too (else its mean)."""
        ctx = make_context(self.robot, q, payload_kg, temp_c)
        v = self.model.predict(self.theta, ctx)
        generator = torch.Generator().manual_seed(seed) if isinstance(seed, int) else seed
        if generator is not None:
            for e, sl in zip(self.model.effects, self.model.slices[1:]):
                if e.name != "joint_clearance":
                    continue
                for j in e.joints:
                    radius = self.clearance_random * self.clearance_tilt_max[j]
                    r = torch.sqrt(torch.rand(len(q), generator=generator, dtype=torch.float64))
                    phi = 2 * torch.pi * torch.rand(len(q), generator=generator, dtype=torch.float64)
                    u = torch.stack([r * torch.cos(phi), r * torch.sin(phi)], -1) * radius
                    v = v + (random_basis(ctx, j, v) @ u.unsqueeze(-1)).squeeze(-1)
        return v

    def measure(self, q, repeats: int = 1, noise_mm: float = 0.02, seed: int | None = None) -> Measurements:
        """Measure commanded poses q (P, n) rad `repeats` times each.

        Returns Measurements with rows in movement order (see module doc), pose ids 0..P-1,
        payload/temperature columns when an effect depends on them.
        """
        q = self.robot.check_q(q).to(torch.float64)
        gen = torch.Generator().manual_seed(self.seed * 1_000_003 + 17 if seed is None else seed)
        P = q.shape[0]
        order = torch.cat([torch.randperm(P, generator=gen) for _ in range(repeats)]) if repeats > 1 \
            else torch.arange(P)
        payload, temp = self._session(len(order), order, P, gen)
        rows_q = q[order]
        xyz = self.positions(rows_q, payload, temp, seed=gen)
        xyz = xyz + noise_mm * torch.randn(xyz.shape, generator=gen, dtype=torch.float64)
        return Measurements(order, rows_q, xyz, payload, temp)
