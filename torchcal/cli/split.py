"""`torchcal split DATA --fraction F --seed S --out TRAIN.csv VAL.csv [--robot R]`: a
seeded train / validation split by pose that keeps the session's sequence.

All rows of one pose go to one side (the distinct pose ids, sorted, permuted by numpy's
``default_rng(S)``; the first ``round(F * poses)`` train; `torchcal.measurements.split_by_pose`).
Rows keep their measurement order, and both files carry ``prev_q1..prev_qN``, the joint
angles each row was approached from in the whole of DATA (`Measurements.q_prev`), so a
split file reads as its rows did in DATA: direction-dependent effects (backlash) see the
same approach directions (docs/formats-measurements.md). The files are written in mm and
degrees (a prismatic joint's column in mm when ``--robot`` names the robot; without it
every q column is an angle)."""

from __future__ import annotations

import sys

from torchcal.cli._args import (add_force, add_robot, add_units, check_outputs, load_robot, read_data, units,
                                seed_int, warnings_to_stderr)


def add_parser(sub):
    p = sub.add_parser("split", help="train / validation split by pose, keeping the approach sequence",
                       description=__doc__.splitlines()[0])
    p.add_argument("data", help="measurement CSV of one session")
    p.add_argument("--fraction", type=float, default=0.6, help="share of poses for training, in (0, 1) "
                                                                 "(default 0.6)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the permutation of poses (default 0)")
    p.add_argument("--out", nargs=2, required=True, metavar=("TRAIN.csv", "VAL.csv"), help="the two files to write")
    add_robot(p, required=False, what="the robot (for prismatic joints' units and the unit check; optional)")
    add_units(p)
    add_force(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from torchcal.errors import InputError
    from torchcal.io.files import all_or_none
    from torchcal.io.measurement_csv import FILE_WARNINGS, read_measurements, write_measurements
    from torchcal.measurements import split_by_pose

    if not 0.0 < args.fraction < 1.0:
        raise InputError(f"--fraction {args.fraction}: expected a share of the poses strictly between 0 and 1")
    train_path, val_path = args.out
    check_outputs([("--out TRAIN", train_path), ("--out VAL", val_path)], args.force, inputs=[args.data])
    robot = load_robot(args.robot)
    if robot is not None:
        m = read_data(args.data, robot, args)
    else:
        with warnings_to_stderr(*FILE_WARNINGS):
            m = read_measurements(args.data, **units(args))
    is_train = split_by_pose(m.pose, args.fraction, args.seed)
    train, val = m.subset(is_train), m.subset(~is_train)
    with all_or_none([train_path, val_path]):  # both files or neither (an error or Ctrl-C between them)
        for path, part in ((train_path, train), (val_path, val)):
            write_measurements(path, part, force=args.force, inputs=[args.data], robot=robot, approach=True)
    n_poses = int(m.pose.unique().numel())
    print(f"{args.data}: {n_poses} poses split by pose (fraction {args.fraction}, seed {args.seed}); "
          f"rows keep the approach they had in the whole session (prev_q columns)")
    for path, part, side in ((train_path, train, "training"), (val_path, val, "validation")):
        k = int(part.pose.unique().numel())
        print(f"wrote {path} ({_count(k, 'pose')}, {_count(len(part), 'row')})")
        if k < FEW_POSES:
            sys.stderr.write(f"torchcal: warning: the {side} file {path} holds {_count(k, 'pose')}: an RMS over "
                             f"fewer than {FEW_POSES} poses says little (choose --fraction so that each side "
                             f"keeps at least {FEW_POSES})\n")
    return 0


#: poses a side of a split should keep: the relative standard error of an RMS over k poses
#: (3 independent error components each) is about 1 / sqrt(6 k), above 18 % below 5 poses
FEW_POSES = 5


def _count(k: int, noun: str) -> str:
    return f"{k} {noun}" + ("" if k == 1 else "s")
