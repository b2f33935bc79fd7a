"""Zone calibration: interval calibration globally and per zone of a partition.

The one implementation behind ``torchcal calibrate``, `torchcal.calibrate` and the
paper's pipeline (`torchcal.workflows.paper_experiment`):

- `fit_zones`: given the poses of each zone (`PoseIntervals`) and a global fit, each
  zone's interval parameters. ``method="damped"`` (default): each zone is the damped
  least-squares solution of eq. 29 towards the global calibration, the damping by
  generalised cross-validation (``damping="gcv_shared"``: one mu for all zones, ``"gcv"``:
  per zone, or a number >= 0); a zone without poses keeps the global parameters.
  ``method="independent"``: each zone on its own from nominal (every zone needs poses,
  and more equations than identifiable parameters).
- `calibrate`: measurements with repeated rows per pose -> the global interval fit (a
  `FitResult` with ``radius``) without a partition, else a `ZonedFit` (every pose goes to
  the zone of its nominal TCP position, `Partition.assign`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import torch

from torchcal.calibration.fit import RANK_TOL, FitResult
from torchcal.calibration.intervals import PoseIntervals, identify_zones, pose_intervals
from torchcal.calibration.model import CalibrationModel
from torchcal.effects.context import Context
from torchcal.errors import DataError, InputError

__all__ = ["ZONE_METHODS", "ZonedFit", "fit_zones", "calibrate"]

ZONE_METHODS = ("damped", "independent")


@dataclass
class ZonedFit(FitResult):
    """A fitted model with one parameter set per zone of a workspace partition (the
    paper's per-zone calibration): a `FitResult` whose own fields are those of the
    global calibration, plus one `FitResult` per zone.

    One fitted-model type rather than a second one beside it: whatever answers "where is
    the TCP, which command reaches this target" takes a FitResult, and a ZonedFit
    answers it zone by zone through the three members it overrides: `zone_theta` (Z, P),
    `assign` (the zone of a position, `Partition.assign`) and `predict` (each row with the
    parameters of the zone of its nominal TCP position). `torchcal.save` /
    `torchcal.load` write and read it as one MODEL.json (`torchcal.io.modelfile`).

    zones: one `FitResult` per zone, zone z + 1 at index z (with ``radius`` and
    ``damping``; a zone without poses holds the global fit itself); partition: the
    `torchcal.partition.zones.Partition` that assigns positions to zones; method: how the
    zones were fitted ("damped" or "independent"); zone_poses: calibration poses per zone.
    """

    zones: list = field(default_factory=list)
    partition: object = None
    method: str = "damped"
    zone_poses: list = field(default_factory=list)

    @classmethod
    def of(cls, glob: FitResult, zones: list, partition, method: str, zone_poses: list) -> "ZonedFit":
        """The global fit `glob` with its zones (one `FitResult` each, partition order)."""
        if partition is not None and partition.n_zones != len(zones):
            raise InputError(f"the partition has {partition.n_zones} zones but the model {len(zones)}")
        base = {f.name: getattr(glob, f.name) for f in fields(FitResult)}
        return cls(**base, zones=list(zones), partition=partition, method=method, zone_poses=list(zone_poses))

    @property
    def zone_theta(self) -> torch.Tensor:
        """(Z, P) parameters of each zone (row z: zone z + 1)."""
        return torch.stack([z.theta for z in self.zones])

    def assign(self, positions: torch.Tensor) -> torch.Tensor:
        """(M,) int64 zone ids 1..Z of positions (M, 3) mm, numbered as in the partition
        (`Partition.assign`) and the file."""
        return self.partition.assign(positions)

    def predict(self, ctx: Context) -> torch.Tensor:
        """(N, 3) mm: each row with the parameters of the zone of its nominal TCP position
        (as ``calibrate`` assigns poses and ``compensate`` targets)."""
        cm = self.model
        zone = self.assign(cm.robot.fk(ctx.q)).to(ctx.q.device) - 1
        out = torch.empty(ctx.q.shape[0], 3, dtype=ctx.q.dtype, device=ctx.q.device)
        for z in zone.unique().tolist():
            rows = (zone == z).nonzero().flatten()
            out[rows] = cm.predict(self.zones[z].theta.to(ctx.q), ctx.subset(rows))
        return out


def fit_zones(model: CalibrationModel, zones: list[PoseIntervals], glob: FitResult | None = None,
              method: str = "damped", damping="gcv_shared", rank_tol: float = RANK_TOL) -> list[FitResult]:
    """One `FitResult` per zone (zone order kept).

    zones: the poses of each zone (an empty `PoseIntervals` for a zone without poses).
    glob: the global interval fit (needed by ``method="damped"``: the prior, and the
    parameters of an empty zone). Raises InputError for an unknown method, or an empty
    zone with ``method="independent"``.
    """
    if method not in ZONE_METHODS:
        raise InputError(f"zone method: expected one of {ZONE_METHODS}, got {method!r}")
    have = [z for z, d in enumerate(zones) if len(d)]
    if method == "independent":
        empty = [z + 1 for z, d in enumerate(zones) if not len(d)]
        if empty:
            counts = ", ".join(f"zone {z + 1}: {len(d)}" for z, d in enumerate(zones))
            raise DataError(f"{'zones' if len(empty) > 1 else 'zone'} {', '.join(map(str, empty))} of the partition "
                            f"{'have' if len(empty) > 1 else 'has'} no poses (poses per zone: {counts}); the "
                            "independent zone method fits each zone on its own poses: measure poses there, or "
                            "use the damped method (a zone without poses keeps the global parameters)")
        return identify_zones(model, list(zones), rank_tol=rank_tol,
                              labels=[f"zone {z + 1} (independent zone method)" for z in range(len(zones))])
    if glob is None:
        raise InputError("fit_zones: method 'damped' needs the global fit (glob)")
    fitted = identify_zones(model, [zones[z] for z in have], theta0=glob.theta, damping=damping, rank_tol=rank_tol,
                            labels=[f"zone {z + 1}" for z in have])
    by_zone = dict(zip(have, fitted))
    return [by_zone.get(z, glob) for z in range(len(zones))]


def check_one_point(meas) -> None:
    """InputError naming the file when `meas` (`Measurements`) hold several point ids:
    interval calibration groups a pose's rows into one interval per axis."""
    if meas.point is not None and len(set(meas.point.tolist())) > 1:
        raise InputError(f"{meas.source or 'measurements'}: interval calibration groups the rows of a pose into "
                         "one interval per axis, which several measured points per pose (point column) would "
                         "mix; use fit / discover (one tool offset per point), or one point id per file")


def calibrate(model: CalibrationModel, meas, partition=None, zone_method: str = "damped",
              damping="gcv_shared") -> FitResult:
    """Interval calibration of `meas` (`Measurements`, >= 2 rows per pose).

    partition: a `torchcal.partition.zones.Partition` or None (global only).
    Returns the global interval fit (a `FitResult` with ``radius``) without a partition,
    else a `ZonedFit` (the global fit and one fit per zone).
    """
    check_one_point(meas)
    from dataclasses import replace

    from torchcal.calibration.joint_range import joint_range, seed_poses

    data = pose_intervals(meas, min_repeats=2, rows=True)  # each pose: its rows' directions, temperatures, payloads
    uses = [e.spec() for e in model.effects if e.uses_approach]
    if uses and bool(data.mixed.any()):
        k = int(data.mixed.nonzero()[0])
        raise InputError(f"{meas.source or 'measurements'}: the rows of pose {int(data.pose[k])} (and "
                         f"{int(data.mixed.sum()) - 1} more) were approached from different directions, which "
                         f"one interval of a pose's repeats mixes, and {', '.join(uses)} depends on the "
                         "direction: measure each pose's repeats without moving away, or fit it with fit / discover")
    glob = replace(identify_zones(model, [data], labels=["the global calibration"])[0], q_range=joint_range(meas.q), seed_poses=seed_poses(meas.q))
    if partition is None:
        return glob
    zone = partition.assign(model.robot.fk(data.q)) - 1  # (m,) 0-based
    members = [(zone == z).nonzero().flatten() for z in range(partition.n_zones)]
    fits = fit_zones(model, [data.subset(m) for m in members], glob, zone_method, damping)
    return ZonedFit.of(glob, fits, partition, zone_method, [len(m) for m in members])
