"""`torchcal compensate TARGETS.csv --model MODEL.json [--frame measuring|base] --out Q.csv`: corrected joint commands
that make the calibrated model reach each target (torchcal.api.compensate_targets).

TARGETS.csv: header ``x,y,z`` (mm; --length-unit m for metres) and optionally ``q1..qN``
(degrees, mm for a prismatic joint; --angle-unit rad, --length-unit m), ``payload_kg`` and
``temp_c`` (the conditions of each move, needed by load- and temperature-dependent
effects): the seed of each target, normally the command that nominally reaches it (a
seed whose model point lies more than 100 mm from its target is named in a warning; seeds
that look like radians read as degrees are refused).
Without seeds the nominal inverse (nominal geometry in the model's fitted frame) is
solved first, each target starting from the nearest of the calibration poses the model
keeps (the arm configuration it was calibrated in; the next nearest when the solution
leaves the joint limits or the calibrated joint range). x,y,z fix 3 joints: the others,
and with them the tool orientation, are those of that pose, and a line says so; with
seeds they stay at the seed's to first order.

Frames (--frame): ``measuring`` (the default, printed) reads x,y,z in the frame the
model was fitted in: the laser tracker's when the model has ``base_frame``;
``base`` reads them in the robot base frame (the robot file's base link), mapped to the
measuring frame with the model's fitted base frame, which holds joint 1's zero offset
and d1 (the data cannot tell them from its rotation about z and z shift): their errors
move base-frame targets by dtheta1 x reach and dd1, and a line says so. For a model
without ``base_frame`` the two are the same. Targets around the origin of the frame or inside the robot's base
(metres read as mm) are refused.

MODEL.json: an interval model of ``torchcal calibrate`` (each target is assigned to a zone
by the partition's `assign` before anything is measured, and compensated with that
zone's center parameters) or a ``torchcal fit`` model (one parameter set).

Q.csv: ``point,zone,q1..qN,residual_mm,converged,within_limits`` with the corrected
commands in degrees, the calibrated model's remaining distance to the target (mm),
whether it met the tolerance and whether the command lies inside the joint limits; zones
are 1-based (1 for a single-set model). The file is written in full (a target that
could not be solved has converged=false: do not send its command); when any target did
not converge or needs a command outside the limits, one stderr line names those targets
(1-based rows) and the command exits 1. Exit 2: bad input, nothing written.
"""

from __future__ import annotations

import sys

from torchcal.cli._args import add_effects_module, add_force, add_robot, add_units, check_outputs, load_robot


TOOL_NOTE_MM = 1.0  # a tool offset beyond this is said: the targets are the reflector's, not the TCP's


def add_parser(sub):
    p = sub.add_parser("compensate", help="corrected joint commands for target positions",
                       description=__doc__.splitlines()[0])
    p.add_argument("targets", help="CSV with columns x,y,z (mm, in --frame) [, q1..qN seeds in degrees]")
    p.add_argument("--frame", choices=("measuring", "base"), default="measuring",
                   help="frame of the targets' x,y,z: measuring (default: the frame the model was fitted in, the "
                        "tracker's) or base (the robot base frame)")
    p.add_argument("--model", required=True, help="MODEL.json (torchcal calibrate or torchcal fit)")
    p.add_argument("--out", required=True, help="output CSV of corrected joint commands (degrees)")
    add_robot(p, required=False, what="check that the model is for this robot (the model file embeds its robot; this one's "
             "joint limits are used: within_limits, seeds)")
    add_units(p, "targets")
    add_force(p)
    add_effects_module(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from torchcal.api import compensate_targets
    from torchcal.calibration.joint_range import CalibratedRangeWarning
    from torchcal.cli._args import units, warnings_to_stderr
    from torchcal.io.files import atomic_write
    from torchcal.io.targets_csv import compensation_csv

    check_outputs([("--out", args.out)], args.force, inputs=[args.targets, args.model])
    from torchcal.calibration.checks.verdict import MismatchWarning

    with warnings_to_stderr(CalibratedRangeWarning, MismatchWarning):  # outside the calibrated range, far seeds
        res = compensate_targets(args.model, args.targets, frame=args.frame, robot=load_robot(args.robot),
                                 **units(args))
    atomic_write(args.out, compensation_csv(res), force=args.force, inputs=[args.targets, args.model])
    d = res.to_dict()
    print(f"compensated {len(d['targets'])} targets (x,y,z in the {args.frame} frame) with {d['n_zones']} "
          f"parameter set(s) ({d['method']}): "
          f"{len(d['targets']) - len(res.failed)} converged within the joint limits; max predicted residual "
          f"{d['max_residual_mm']:.3g} mm; wrote {args.out}")
    if args.frame == "base" and res.base_frame_fitted:
        print("--frame base: the fitted base frame holds joint 1's zero offset and d1 (measurements cannot tell them "
              "from its rotation about z and its z shift); their errors move base-frame targets, by dtheta1 x reach "
              "and dd1; measuring-frame targets are free of them")
    u = res.tool_offset_mm
    if u is not None and sum(v * v for v in u) ** 0.5 > TOOL_NOTE_MM:  # which point reaches the targets
        print(f"x,y,z are reached by the measured point of the calibration (the reflector): the model's tool offset "
              f"[{u[0]:.3f}, {u[1]:.3f}, {u[2]:.3f}] mm from the robot file's tool, not the robot file's TCP; for "
              "another point of the tool, move each target by its offset from the reflector")
    if not res.seeded and res.q_user.shape[-1] > 3:
        print(f"{args.targets}: no seeds (q1..qN): x,y,z fix 3 of the {res.q_user.shape[-1]} joints, so each command "
              f"keeps the arm configuration and tool orientation of the nearest calibration pose, not a chosen "
              f"one; give each target's nominal command as q1..qN to keep its orientation")
    if res.failed:
        def rows(ix):
            return ", ".join(map(str, ix[:20])) + (" ..." if len(ix) > 20 else "")
        parts = ([f"not converged: target(s) {rows(d['not_converged'])}"] if d["not_converged"] else []) + \
                ([f"outside the joint limits: target(s) {rows(d['outside_limits'])}"] if d["outside_limits"] else []) + \
                ([f"beyond the reach of {d['robot']}: target(s) {rows(d['beyond_reach'])}, x,y,z read in the "
                  f"{args.frame} frame (--frame {'base' if args.frame == 'measuring' else 'measuring'} for the other)"]
                 if d["beyond_reach"] else [])
        sys.stderr.write(f"torchcal compensate: error: {len(res.failed)} target(s) failed "
                         f"({'; '.join(parts)}); see {args.out}\n")
        return 1
    return 0
