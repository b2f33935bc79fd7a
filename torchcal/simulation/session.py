"""A simulated measurement session (``torchcal simulate``): `simulate` and its `Simulation`.

n seeded random poses of a `VirtualRobot` (the nominal robot with `effects` whose true
parameters are drawn with `seed`), each measured `repeats` times with Gaussian noise; the
true parameters come back with the measurements (written in file units by
`torchcal.io.truth_file`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch

from torchcal.measurements import Measurements
from torchcal.robots.robot import Robot


#: noise (1 sigma per axis, mm) below which `simulate` warns: no instrument that measures a
#: robot's TCP is quieter than about a micrometre (a laser tracker's noise and repeatability
#: are a few um and up; its MPE 15 um + 6 um/m), so a smaller value is likely metres
#: (0.00002 for 0.02 mm). 0 (noise-free data) is silent; the README's 0.02 and the tests'
#: 0.01 .. 0.05 are 10-50x above it.
MIN_NOISE_MM = 0.001


class NoiseUnitWarning(UserWarning):
    """A simulated measurement noise that no instrument has: likely in another unit."""


def warn_noise(noise_mm: float, stacklevel: int = 2) -> bool:
    """One `NoiseUnitWarning` (True) when 0 < noise_mm < MIN_NOISE_MM."""
    if not 0 < noise_mm < MIN_NOISE_MM:
        return False
    warnings.warn(f"noise {noise_mm:g} mm is below {MIN_NOISE_MM:g} mm (1 micrometre), quieter than any laser "
                  f"tracker: in metres? ({1000 * noise_mm:g} mm); 0 simulates noise-free data", NoiseUnitWarning,
                  stacklevel=stacklevel + 1)
    return True


@dataclass
class Simulation:
    """A simulated measurement session (``torchcal simulate``).

    measurements: the `Measurements` (rows in movement order); robot: the nominal `Robot`;
    effects: the virtual robot's effect specs; theta: (P,) its true parameters (model units);
    parameter_names: (P,) their names; seed, pose_seed: the robot's seed and the seed of
    the poses and the session; repeats, noise_mm."""

    measurements: Measurements
    robot: Robot
    effects: list
    theta: torch.Tensor
    parameter_names: list
    seed: int
    pose_seed: int
    repeats: int
    noise_mm: float

    def to_dict(self) -> dict:
        m = self.measurements
        return {"robot": self.robot.name, "effects": list(self.effects), "rows": len(m),
                "poses": len(m) // self.repeats, "repeats": self.repeats, "noise_mm": self.noise_mm,
                "seed": self.seed, "pose_seed": self.pose_seed,
                "columns": [c for c, v in (("payload_kg", m.payload_kg), ("temp_c", m.temp_c)) if v is not None]}


def simulate(robot: Robot, effects=(), *, n: int = 50, repeats: int = 1, noise_mm: float = 0.02, seed: int = 0,
             pose_seed: int | None = None) -> Simulation:
    """n random poses of a virtual robot (`robot` with `effects` whose true parameters are
    drawn with `seed`), each measured `repeats` times with noise_mm (1 sigma per axis).
    pose_seed: seed of the poses and the session (default `seed`; another value gives fresh
    poses of the same virtual robot)."""
    from torchcal.effects.spec import parse_specs
    from torchcal.errors import number_argument
    from torchcal.simulation.virtual_robot import VirtualRobot, random_poses

    n, repeats = number_argument("n", n, integer=True, at_least=1), number_argument("repeats", repeats, integer=True,
                                                                                     at_least=1)
    noise_mm = number_argument("noise_mm", noise_mm, at_least=0)
    warn_noise(noise_mm, stacklevel=3)  # through torchcal.api.simulate
    specs = [str(s) for s in parse_specs(list(effects), robot.n)] if effects else []
    ps = seed if pose_seed is None else pose_seed
    q = random_poses(robot, n, torch.Generator().manual_seed(ps))
    vr = VirtualRobot(robot, specs, seed=seed)
    # the session's seed as VirtualRobot.measure derives it from its own seed (the same file without pose_seed)
    m = vr.measure(q, repeats=repeats, noise_mm=noise_mm, seed=ps * 1_000_003 + 17)
    return Simulation(m, robot, specs, vr.theta, vr.model.param_names(), seed, ps, repeats, noise_mm)
