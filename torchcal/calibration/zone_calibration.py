"""Zone calibration: interval calibration globally and per zone of a partition.

The one implementation behind ``torchcal calibrate``, `torchcal.calibrate` and the
paper's pipeline (`torchcal.workflows.paper_experiment`):

- `fit_zones`: given the poses of each zone (`PoseIntervals`) and a global fit, each
  zone's interval parameters, all zones batched. ``method="damped"`` (default): each zone
  is the damped least-squares solution of eq. 29 towards the global calibration, the
  damping by generalised cross-validation (``damping="gcv_shared"``: one mu for all
  zones, ``"gcv"``: per zone, or a number >= 0); a zone without poses keeps the global
  parameters. ``method="independent"``: each zone on its own from nominal (every zone
  needs poses, and more equations than identifiable parameters).
- `calibrate`: measurements with repeated rows per pose -> an `IntervalModel` (one
  global zone without a partition; otherwise every pose goes to the zone of its nominal
  TCP position, `Partition.assign`).
"""

from __future__ import annotations

from torchcal.calibration.fit import RANK_TOL
from torchcal.calibration.intervals import IntervalFit, IntervalModel, PoseIntervals, identify_zones, pose_intervals
from torchcal.calibration.model import CalibrationModel
from torchcal.errors import InputError

ZONE_METHODS = ("damped", "independent")


def fit_zones(model: CalibrationModel, zones: list[PoseIntervals], glob: IntervalFit | None = None,
              method: str = "damped", damping="gcv_shared", rank_tol: float = RANK_TOL) -> list[IntervalFit]:
    """One `IntervalFit` per zone (zone order kept).

    zones: the poses of each zone (an empty `PoseIntervals` for a zone without poses).
    glob: the global `IntervalFit` (needed by ``method="damped"``: the prior, and the
    parameters of an empty zone). Raises InputError for an unknown method, or an empty
    zone with ``method="independent"``.
    """
    if method not in ZONE_METHODS:
        raise InputError(f"zone method: expected one of {ZONE_METHODS}, got {method!r}")
    have = [z for z, d in enumerate(zones) if len(d)]
    if method == "independent":
        empty = [z + 1 for z, d in enumerate(zones) if not len(d)]
        if empty:
            raise InputError(f"zone(s) {empty} have no poses; the independent zone method needs poses in every zone")
        return identify_zones(model, list(zones), rank_tol=rank_tol)
    if glob is None:
        raise InputError("fit_zones: method 'damped' needs the global fit (glob)")
    fitted = identify_zones(model, [zones[z] for z in have], theta0=glob.theta, damping=damping, rank_tol=rank_tol)
    by_zone = dict(zip(have, fitted))
    return [by_zone.get(z, glob) for z in range(len(zones))]


def calibrate(model: CalibrationModel, meas, partition=None, zone_method: str = "damped",
              damping="gcv_shared") -> tuple[IntervalModel, IntervalFit]:
    """Interval calibration of `meas` (`Measurements`, >= 2 rows per pose).

    partition: a `torchcal.partition.zones.Partition` or None (global only).
    Returns (`IntervalModel`, the global `IntervalFit`).
    """
    if meas.point is not None and len(set(meas.point.tolist())) > 1:
        raise InputError(f"{meas.source or 'measurements'}: interval calibration groups the rows of a pose into "
                         "one interval per axis, which several measured points per pose (point column) would "
                         "mix; use fit / discover (one tool offset per point), or one point id per file")
    from torchcal.calibration.joint_range import joint_range, seed_poses

    data = pose_intervals(meas, min_repeats=2)
    glob = identify_zones(model, [data])[0]
    if partition is None:
        out = IntervalModel.from_fits([glob], poses=[len(data)], method="global")
        out.q_range, out.seed_poses = joint_range(meas.q), seed_poses(meas.q)
        return out, glob
    zone = partition.assign(model.robot.fk(data.q)) - 1  # (m,) 0-based
    members = [(zone == z).nonzero().flatten() for z in range(partition.n_zones)]
    fits = fit_zones(model, [data.subset(m) for m in members], glob, zone_method, damping)
    levels = [int(v) for v in partition.zone_level]
    out = IntervalModel.from_fits(fits, partition, levels, [len(m) for m in members], zone_method)
    out.q_range, out.seed_poses = joint_range(meas.q), seed_poses(meas.q)
    for z, m in enumerate(members):
        if not len(m):
            out.zones[z]["note"] = "no poses in this zone: global parameters"
    return out, glob
