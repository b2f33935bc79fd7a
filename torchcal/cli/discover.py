"""`torchcal discover DATA --robot R [--json OUT] [--out MODEL.json] [--rrd FILE]
[--transfer OTHER.csv [--transfer-poses K]]`: add the best significant effect each round
until none is left; the error falls at each round.
Tracker data (in the instrument's frame, a reflector on the flange) need `--effects
base_frame tool_offset`; without them such data are refused before any work, since the
robot's links would otherwise absorb the frame and the reflector.

``--transfer OTHER.csv``: measurements of the same robot from another session as a check.
Each round's model is registered (frame only, as `torchcal register` does) on OTHER's
first K poses (``--transfer-poses``, default 30) and its error on OTHER's other poses is
printed; a step that does not lower it beyond chance (the in-session refit test, on
OTHER's poses) is refused ("helps within the session only"), the next candidate that
met the acceptance rule is tried, and a round with none left ends the discovery
(docs/diagnosis.md). Without --transfer the output says that transfer was not tested."""

from __future__ import annotations

from pathlib import Path

from torchcal.cli._args import (add_cv, add_device, add_effects_module, add_force, add_units, add_viz, check_folder,
                                check_outputs, device_of, read_data, add_robot, positive_int, robot_inputs)
from torchcal.cli.diagnose import add_sigmas, print_step
from torchcal.cli.fit import residual_stage_line
from torchcal.errors import InputError

#: what discover without --transfer says about its effects
NOT_TESTED = ("transfer to another session: not tested. The effects above lower the error within this session "
              "(its cross-validation folds share one set-up and day); terms of the session cannot be told from the "
              "robot's here. --transfer OTHER.csv (another session of this robot) keeps a step only when it lowers "
              "OTHER's held-out error beyond chance (docs/diagnosis.md).")


def add_parser(sub):
    p = sub.add_parser("discover", help="add missing effects round by round", description=__doc__)
    p.add_argument("data", help="measurement CSV")
    add_robot(p)
    p.add_argument("--effects", nargs="*", default=[], metavar="SPEC", help="effects to start from; tracker data (in the instrument's frame, a reflector on the flange) need base_frame tool_offset")
    add_cv(p)
    add_sigmas(p)
    p.add_argument("--json", help="write the history here")
    p.add_argument("--out", help="write the final MODEL.json here")
    p.add_argument("--transfer", metavar="OTHER.csv", help="measurements of another session: keep a step only "
                                                         "if it lowers that session's error beyond chance")
    p.add_argument("--transfer-poses", type=positive_int, default=30, metavar="K",
                   help="poses of OTHER.csv the frame is registered on (default 30)")
    p.add_argument("--residual-model", choices=["kernel"],
                   help="add the non-physical residual stage to the final model when its held-out gain is "
                        "significant (as fit --residual-model; docs/residual-model.md)")
    add_viz(p)
    add_units(p)
    add_force(p)
    add_effects_module(p)
    add_device(p, "the fits")
    p.set_defaults(func=run)


def run(args) -> int:
    from torchcal import api
    from torchcal.io import modelfile
    from torchcal.io.files import write_json
    from torchcal.io.robot_file import robot as make_robot

    device = device_of(args)  # a refused --device before any work
    check_outputs([("--json", args.json), ("--out", args.out), ("--rrd", args.rrd)], args.force,
                  inputs=[args.data, args.transfer, *robot_inputs(args.robot)])
    check_folder("--plots", args.plots)
    if args.rrd or args.plots:  # the PNG names too, before any work
        from torchcal.cli._viz import check_outputs as check_visual_outputs
        check_visual_outputs(args, "discover")
    robot = make_robot(args.robot).to(device)
    if args.transfer is not None and Path(args.transfer).resolve() == Path(args.data).resolve():
        raise InputError(f"{args.transfer}: --transfer names DATA itself; give another session's measurements")
    m = read_data(args.data, robot, args).to(device)
    other = None if args.transfer is None else read_data(args.transfer, robot, args).to(device)
    if other is not None:
        from torchcal.diagnosis.transfer import TransferCheck
        print(TransferCheck(other, args.transfer_poses, args.transfer).describe())
    from torchcal.cli._args import sigma_deg, warnings_to_stderr
    from torchcal.cli._progress import progress
    from torchcal.diagnosis.spectral import NarrowRangeWarning

    from torchcal.calibration.checks.row_order import RowOrderWarning

    with warnings_to_stderr(NarrowRangeWarning, RowOrderWarning), progress("discover", f"searching effects on {len(m)} rows"):
        res = api.discover(robot, m, args.effects, folds=args.folds, seed=args.seed, sigma_mm=args.sigma_mm,
                           sigma_deg=sigma_deg(args, m), transfer=other, transfer_poses=args.transfer_poses,
                           residual_model=args.residual_model)
    for i, (h, d) in enumerate(zip(res.history, res.diagnoses)):
        print(f"round {i}:")
        print_step(d.step)
        if "transfer" in h:
            from torchcal.diagnosis.transfer import describe_verdict
            print("\n".join(describe_verdict(h["transfer"])))
    print(res.final_words())
    if other is None:
        print(NOT_TESTED)
    if res.unexplained is not None:
        print(res.unexplained.describe())
    if args.residual_model:
        print(residual_stage_line(res.fit))
    if args.json:
        write_json(args.json, res.to_dict(), force=args.force, inputs=[args.data])
        print(f"wrote {args.json}")
    if args.out:
        write_json(args.out, modelfile.to_dict(res.fit, source=args.data, seed=args.seed,
                                               pose_ids=m.pose.tolist()),
                   force=args.force, inputs=[args.data])
        print(f"wrote {args.out}")
    if args.rrd or args.plots:
        from torchcal.cli._viz import discovery_outputs
        with progress("discover", "drawing figures"):
            discovery_outputs(args, robot, m, res)
    return 0
