"""Configuration of the paper's experiment (`torchcal demo`): `DemoConfig` (every size and
seed the experiment depends on, mm and degrees), the compared methods and the paper's
published figures. The experiment: `torchcal.workflows.paper_experiment`; its report:
`torchcal.workflows.paper_report`."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from torchcal.errors import InputError

AXES = ("x", "y", "z")
BOUNDS = ("lower", "upper")
#: docs/paper.md section 6, the headline reductions after partitioned compensation (percent).
PAPER_REDUCTION_PERCENT = {"x": {"lower": 40.16, "upper": 59.36}, "y": {"lower": 59.08, "upper": 40.87},
                           "z": {"lower": 54.24, "upper": 33.98}}

#: method -> (per zone?, description). The first four are the issue's side-by-side.
METHODS = {
    "paper_partitioned": (True, "the paper: geometric + base_frame per zone, eq. 29 damped LS, mu = paper_mu"),
    "global_geometric": (False, "geometric + base_frame fitted once to the same poses"),
    "discovered_global": (False, "global, geometric + the effects discover finds on the calibration data"),
    "discovered_partitioned": (True, "discovered_global + per-zone geometric correction (damped, mu = paper_mu)"),
    "paper_partitioned_gcv": (True, "variant of the paper: mu per zone by GCV"),
    "paper_partitioned_more": (True, "variant of the paper: points_per_zone_more poses per zone"),
}
MAIN_METHODS = ("paper_partitioned", "global_geometric", "discovered_global", "discovered_partitioned")


@dataclass(frozen=True)
class DemoConfig:
    """Everything the demo depends on (mm, degrees). Sizes: docs/demo.md.

    Attributes:
        robot: preset name.
        seed: seed of every random draw (seed s of a K-seed run: seed + s).
        n_sweep, sweep_source, sweep_samples: the sweep (Table 3): Latin-hypercube points;
            "model" (the clearance interval model of Table 2) or "measured" (`repeats` moves
            of the virtual robot); clearance states per point of the model sweep.
        repeats: moves to each point (sweep, calibration, test).
        allowed_distance_mm, allowed_axis_mm: allowed errors [0, D] and +-a (Tables 3, 5).
        zones_per_level: sub-zones of each reliability level (levels = its length).
        points_per_zone: calibration poses per zone (the paper: 10).
        points_per_zone_more: poses per zone of the "more poses" variant.
        test_per_zone: fresh test points per zone.
        truth_effects: the virtual robot's effects besides the MD-H deviations.
        geometric_scale: factor on the MD-H deviation sizes (0.5 mm, 0.02 deg).
        base_offset_mm, base_tilt_deg: measurement-frame translation and rotation vector.
        compliance_mm, gear_mm: TCP RMS of joint compliance (payload 0..rated) and of the gear error.
        clearance_mm: clearance size for robots without a Table 2 (the Titan's is Table 2).
        clearance_random: share of the clearance tilt that is random per move.
        noise_mm: measurement noise (standard deviation per axis).
        paper_mu: eq. 29 damping of the per-zone fits (relative to the column norms).
        discover_rounds: effects `discover` may add at most (0: no discovery).
        rank_tol: identifiability threshold (pivot ratio of the scaled Jacobian).
    """

    robot: str = "kr1000titan"
    seed: int = 0
    n_sweep: int = 100
    sweep_source: str = "model"
    sweep_samples: int = 300
    repeats: int = 10
    allowed_distance_mm: float = 2.5
    allowed_axis_mm: float = 1.0
    zones_per_level: tuple = (3, 2, 3, 2)
    points_per_zone: int = 10
    points_per_zone_more: int = 30
    test_per_zone: int = 2
    truth_effects: tuple = ("base_frame", "joint_compliance:2,3", "gear_periodic:2,3",
                            "joint_clearance:1,2,3,4,5,6")
    geometric_scale: float = 2.0
    base_offset_mm: tuple = (0.3, -0.2, 0.25)
    base_tilt_deg: tuple = (0.001, -0.001, 0.001)
    compliance_mm: float = 1.0
    gear_mm: float = 0.5
    clearance_mm: float = 0.3
    clearance_random: float = 0.5
    noise_mm: float = 0.03
    paper_mu: float = 1e-3
    discover_rounds: int = 2
    rank_tol: float = 1e-6

    def check(self) -> None:
        """Raise InputError naming the first bad field."""
        if self.sweep_source not in ("model", "measured"):
            raise InputError(f"DemoConfig.sweep_source: expected 'model' or 'measured', got {self.sweep_source!r}")
        for name in ("n_sweep", "sweep_samples", "repeats", "points_per_zone", "points_per_zone_more",
                     "test_per_zone"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InputError(f"DemoConfig.{name}: expected a positive integer, got {v!r}")
        if self.repeats < 2:
            raise InputError(f"DemoConfig.repeats: intervals need at least 2 repetitions, got {self.repeats}")
        if not self.zones_per_level or any(int(k) < 1 for k in self.zones_per_level):
            raise InputError(f"DemoConfig.zones_per_level: expected positive zone counts, got {self.zones_per_level!r}")
        if isinstance(self.discover_rounds, bool) or not isinstance(self.discover_rounds, int) \
                or self.discover_rounds < 0:
            raise InputError(f"DemoConfig.discover_rounds: expected an integer >= 0, got {self.discover_rounds!r}")
        for name in ("allowed_distance_mm", "allowed_axis_mm", "paper_mu"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"DemoConfig.{name}: expected a positive number, got {v!r}")
        if "base_frame" not in self.truth_effects:
            raise InputError("DemoConfig.truth_effects: the measurement frame 'base_frame' must be among them")

    def to_json(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}
