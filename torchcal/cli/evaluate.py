"""`torchcal evaluate DATA --model MODEL.json [--robot ROBOT] [--json OUT]`: distance errors
measured - model. The model file embeds its nominal robot; ``--robot`` only checks it."""

from __future__ import annotations

from torchcal.io import modelfile
from torchcal.cli._args import add_effects_module, add_force, add_units, check_outputs, read_data, add_robot, load_robot, check_data_joints
from torchcal.effects import context_of
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
    """{"n", "rms_mm", "mean_mm", "max_mm", "per_axis_rms_mm"} of measured - model, and
    "orientation_rms_deg" when the data carry rx, ry, rz and the model was fitted to
    orientations."""
    import math

    from torchcal.calibration.fit import _so3_error

    ctx = context_of(model.robot, m)
    model.check_context(ctx)
    err = m.xyz - model.predict(theta, ctx)
    d = err.norm(dim=-1)
    rep = {"n": len(m), "rms_mm": float(d.pow(2).mean().sqrt()), "mean_mm": float(d.mean()),
           "max_mm": float(d.max()), "per_axis_rms_mm": err.pow(2).mean(0).sqrt().tolist()}
    tool_r = getattr(model, "tool_rotation", None)
    if m.rxyz is not None and tool_r is not None:
        e = _so3_error(model.predict_rotation(theta, ctx) @ tool_r.to(theta), m.rotation)
        rep["orientation_rms_deg"] = math.degrees(float(e.norm(dim=-1).pow(2).mean().sqrt()))
    return rep


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
    return 0
