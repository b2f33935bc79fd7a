"""`torchcal calibrate DATA --robot R [--partition PARTITION.json] --out MODEL.json`: interval
calibration from a measurement CSV with repeated measurements per pose.

Each pose's repeats give per-axis error intervals; the model (geometric MD-H deviations
plus ``--effects``) is identified on the interval centers and the interval radii are
propagated through the linearised solution map (torchcal.calibration.intervals).

- Without ``--partition``: one global interval calibration.
- With ``--partition`` (a JSON of ``torchcal partition``): every pose goes to the zone of
  its nominal TCP position (`Partition.assign`) and each zone gets its own interval
  parameters, all zones in one batched solve. ``--zone-method damped`` (default): a
  global calibration first, then each zone as the damped least-squares solution (eq. 29)
  towards it, the damping chosen by generalised cross-validation (``--damping``; a
  choice at the top of its grid, 10, is named in one warning line: GCV would damp further,
  the zones' poses barely move their parameters from the global calibration);
  a zone without poses keeps the global parameters. ``--zone-method independent``: each
  zone on its own from nominal (the paper's eq. 29 literally; every zone needs more
  equations than identifiable parameters).
  The partition must be made for --robot: its record of the robot (name, fingerprint of
  the nominal kinematics and joint limits) is checked, and a partition of another robot,
  or of other joint limits, is refused with one line naming what differs; a partition
  file of an older torchcal (no record) is used with a warning that it was not checked.

Tracker data (in the instrument's frame, a reflector on the flange) need ``--effects
base_frame tool_offset``; without them the data are refused with that cause, as ``fit``
refuses them (docs/registration.md), and so is a global fit still off by more than any
calibrated arm.

MODEL.json: the file of ``torchcal fit`` (`torchcal.io.modelfile`; the global fit, each
parameter with its interval) plus, with ``--partition``, the partition and each zone's
parameters and intervals; read by ``torchcal compensate``, ``evaluate``, ``export``, ``report``.
"""

from __future__ import annotations

from torchcal.cli._args import (add_effects_module, add_force, add_robot, add_units, check_outputs, nonneg_float,
                                read_data, warnings_to_stderr)


def _damping(text: str):
    if text in ("gcv", "gcv_shared"):
        return text
    import argparse

    try:
        return nonneg_float(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected 'gcv', 'gcv_shared' or a number >= 0, got {text!r}") from None


def add_parser(sub):
    p = sub.add_parser("calibrate", help="interval calibration (global or per zone) from repeated measurements",
                       description=__doc__.splitlines()[0])
    p.add_argument("data", help="measurement CSV with repeated measurements per pose")
    add_robot(p)
    p.add_argument("--partition", help="PARTITION.json (torchcal partition): calibrate per zone")
    p.add_argument("--effects", nargs="*", default=[], metavar="SPEC",
                   help="effects fitted with the geometric deviations, e.g. base_frame joint_clearance")
    p.add_argument("--zone-method", choices=["damped", "independent"], default="damped",
                   help="per-zone method (default damped towards the global calibration)")
    p.add_argument("--damping", type=_damping, default="gcv_shared",
                   help="zone damping mu: gcv_shared (default), gcv (per zone) or a number >= 0")
    p.add_argument("--out", required=True, help="MODEL.json to write")
    add_units(p)
    add_force(p)
    add_effects_module(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    import torchcal
    from torchcal.io.partition_file import load_partition
    from torchcal.io.robot_file import UnrecordedRobotWarning, robot as make_robot
    from torchcal.calibration.identifiability import unidentified_lines
    from torchcal.effects.spec import parse_specs

    check_outputs([("--out", args.out)], args.force, inputs=[args.data, args.partition])
    robot = make_robot(args.robot)
    specs = [str(s) for s in parse_specs(args.effects, robot.n)] if args.effects else []
    with warnings_to_stderr(UnrecordedRobotWarning):  # a partition file without a record
        part = load_partition(args.partition, robot) if args.partition else None
    meas = read_data(args.data, robot, args)
    from torchcal.calibration.checks.verdict import MismatchWarning

    with warnings_to_stderr(MismatchWarning):  # rows beyond the swept region
        res = torchcal.calibrate(robot, meas, specs, partition=part, zone_method=args.zone_method,
                                 damping=args.damping)
    torchcal.save(res, args.out, source=args.data, partition_source=args.partition, force=args.force)
    rep = res.report
    print(f"calibrate {robot.name} + [{', '.join(res.model.specs()) or 'geometric only'}] on {len(meas)} rows "
          f"({rep.n_rows} poses): global fit rms {res.rms_mm:.4f} mm, "
          f"{rep.rank} identified parameters, condition {rep.condition:.3g}")
    if rep.held:
        print(f"held (not identifiable from these poses): {', '.join(rep.held)}")
        for line in unidentified_lines(res.model, rep.held, meas):
            print(line)
    if part is not None:
        print(f"{'zone':>4} {'level':>5} {'poses':>5} {'rms mm':>8} {'held':>4} {'mu':>7}")
        for z, (f, poses) in enumerate(zip(res.zones, res.zone_poses)):
            note = "" if poses else "  no poses in this zone: global parameters"
            print(f"{z + 1:>4} {int(part.zone_level[z]):>5} {poses:>5} {f.rms_mm:>8.4f} {len(f.report.held):>4} "
                  f"{f.damping:>7.0e}{note}")
    print(f"wrote {args.out}")
    return 0
