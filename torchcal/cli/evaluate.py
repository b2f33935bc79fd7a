"""`torchcal evaluate DATA --model MODEL.json [--robot ROBOT] [--json OUT]`: distance errors
measured - model. The model file embeds its nominal robot; ``--robot`` only checks it."""

from __future__ import annotations

from torchcal.io import modelfile
from torchcal.cli._args import (add_effects_module, add_force, add_units, check_outputs, read_data, add_robot,
                                load_robot, check_data_joints, warnings_to_stderr)
from torchcal.io.files import write_json


def add_parser(sub):
    p = sub.add_parser("evaluate", help="errors of a fitted model on a measurement CSV", description=__doc__)
    p.add_argument("data", help="measurement CSV")
    p.add_argument("--model", required=True, help="MODEL.json from `torchcal fit`")
    add_robot(p, required=False, what="check that the model is for this robot")
    p.add_argument("--json", help="write the report here")
    add_units(p)
    add_force(p)
    add_effects_module(p)
    p.set_defaults(func=run)


def evaluate(model, theta, m) -> dict:
    """The report dict of `torchcal.evaluate` ((model, theta) on measurements m); rows
    outside the model's calibrated joint range: one warning line on stderr."""
    from torchcal.api import evaluate as run
    from torchcal.calibration.joint_range import CalibratedRangeWarning

    with warnings_to_stderr(CalibratedRangeWarning):
        return run((model, theta), m).to_dict()


def run(args) -> int:
    check_outputs([("--json", args.json)], args.force, inputs=[args.data, args.model])
    robot = load_robot(args.robot)  # unknown robot: its own clear message
    model, theta = modelfile.load(args.model, robot=robot)
    check_data_joints(args.data, model.robot, args.model)
    m = read_data(args.data, model.robot, args)
    rep = evaluate(model, theta, m)
    if args.json:
        write_json(args.json, rep, force=args.force, inputs=[args.data, args.model])
    x, y, z = rep["per_axis_rms_mm"]
    print(f"{rep['n']} rows: rms {rep['rms_mm']:.4f} mm, mean {rep['mean_mm']:.4f} mm, "
          f"max {rep['max_mm']:.4f} mm; per axis rms x {x:.4f} y {y:.4f} z {z:.4f} mm"
          + (f"; orientation rms {rep['orientation_rms_deg'] * 1000:.4g} mdeg"
             if "orientation_rms_deg" in rep else ""))
    if getattr(model, "residual_model", None) is not None:
        print("(errors of the physical model plus its non-physical residual stage, docs/residual-model.md)")
    return 0
