"""`torchcal evaluate DATA --model MODEL.json [--robot ROBOT] [--json OUT] [--residuals OUT.csv]
[--plots DIR] [--rrd FILE]`: distance errors measured - model, typically on held-out poses.
The model file embeds its nominal robot; ``--robot`` checks it (another geometry is refused)
and, when its joint limits differ, gives the model its limits, with one warning line.

Prints the RMS, mean, 95th percentile and maximum of the distance error and the per-axis
RMS (`torchcal.metrics.error_summary`, as ``torchcal report``), and ISO 9283 AP and RP
when some pose is measured 3 times or more (docs/report.md).

``--residuals OUT.csv`` writes one row per measurement, in the data file's order:
``row,pose[,point],ex_mm,ey_mm,ez_mm,e_mm[,orientation_deg][,outside_range]`` (row: the
data row, 1-based; e = measured - model, mm; orientation_deg: the orientation error angle
when the data carry rx, ry, rz and the model was fitted to them; outside_range: true for a
row outside the joint range the model was calibrated on, when the model records it).
Pooled cross-validation: concatenate the folds' files.

``--plots DIR`` / ``--rrd FILE`` show where the model fails on these rows, with the
figures of ``diagnose``: the error over the workspace (3-D, coloured), the residual
against each joint angle and against every variable (docs/diagnosis.md)."""

from __future__ import annotations

from torchcal.cli._args import (add_effects_module, add_force, add_units, add_viz, check_outputs, read_data,
                                add_robot, load_robot, check_data_joints, warnings_to_stderr)


def add_parser(sub):
    p = sub.add_parser("evaluate", help="errors of a fitted model on a measurement CSV", description=__doc__)
    p.add_argument("data", help="measurement CSV")
    p.add_argument("--model", required=True,
                   help="MODEL.json from `torchcal fit` or `calibrate` (per zone: each row with its zone's parameters)")
    add_robot(p, required=False, what="check that the model is for this robot (its joint limits are used)")
    p.add_argument("--json", help="write the report here")
    p.add_argument("--residuals", metavar="OUT.csv", help="write one row per measurement (errors in mm) here")
    add_viz(p)
    add_units(p)
    add_force(p)
    add_effects_module(p)
    p.set_defaults(func=run)


def evaluate(fitted, m):
    """The `torchcal.evaluate` result (fitted model `FitResult` on measurements m); rows
    outside the model's calibrated joint range: one warning line on stderr."""
    from torchcal.api import evaluate as run
    from torchcal.calibration.joint_range import CalibratedRangeWarning

    from torchcal.calibration.checks.verdict import MismatchWarning

    with warnings_to_stderr(CalibratedRangeWarning, MismatchWarning):
        return run(fitted, m)


def residuals_csv(m, ev) -> str:
    """The ``--residuals`` CSV text (module doc) of Evaluation `ev` on measurements m."""
    cols = ["row", "pose"] + (["point"] if m.point is not None else []) + ["ex_mm", "ey_mm", "ez_mm", "e_mm"]
    cols += (["orientation_deg"] if ev.orientation_deg is not None else [])
    cols += (["outside_range"] if ev.outside is not None else [])
    err = ev.residuals_mm.detach().to("cpu", dtype=ev.residuals_mm.dtype).double()
    e = err.norm(dim=-1).tolist()
    pose = m.pose.tolist()
    point = m.point.tolist() if m.point is not None else None
    orient = ev.orientation_deg.tolist() if ev.orientation_deg is not None else None
    out = ev.outside.tolist() if ev.outside is not None else None
    lines = [",".join(cols)]
    for i, (x, y, z) in enumerate(err.tolist()):
        row = [str(i + 1), str(pose[i])] + ([str(point[i])] if point is not None else [])
        row += [repr(x), repr(y), repr(z), repr(e[i])]
        row += [repr(orient[i])] if orient is not None else []
        row += ["true" if out[i] else "false"] if out is not None else []
        lines.append(",".join(row))
    return "\n".join(lines) + "\n"


def _iso9283(m, ev) -> dict | None:
    """`torchcal.metrics.iso9283` of the rows when some pose is measured 3 times or more, else None."""
    from torchcal.metrics import iso9283, pose_groups

    group, keys = pose_groups(m.pose, m.point)
    iso = iso9283(ev.residuals_mm, group, keys)
    return iso if iso["rp_mm"] is not None else None


def run(args) -> int:
    from torchcal.io import modelfile
    from torchcal.io.files import write_json

    from torchcal.io.files import atomic_write

    inputs = [args.data, args.model]
    check_outputs([("--json", args.json), ("--residuals", args.residuals), ("--rrd", args.rrd)], args.force,
                  inputs=inputs)
    if args.rrd or args.plots:  # the PNG names too, before any work
        from torchcal.cli._viz import check_outputs as check_visual_outputs
        check_visual_outputs(args, "evaluate")
    robot = load_robot(args.robot)  # unknown robot: its own clear message
    fitted = modelfile.load(args.model, robot=robot)
    model = fitted.model
    check_data_joints(args.data, model.robot, args.model)
    m = read_data(args.data, model.robot, args)
    ev = evaluate(fitted, m)
    rep = ev.to_dict()
    if args.json:
        write_json(args.json, rep, force=args.force, inputs=inputs)
    if args.residuals:
        atomic_write(args.residuals, residuals_csv(m, ev), force=args.force, inputs=inputs)
    x, y, z = rep["per_axis_rms_mm"]
    print(f"{rep['n']} rows: rms {rep['rms_mm']:.4f} mm, mean {rep['mean_mm']:.4f} mm, "
          f"p95 {rep['p95_mm']:.4f} mm, max {rep['max_mm']:.4f} mm; per axis rms x {x:.4f} y {y:.4f} z {z:.4f} mm"
          + (f"; orientation rms {rep['orientation_rms_deg'] * 1000:.4g} mdeg"
             if "orientation_rms_deg" in rep else ""))
    iso = _iso9283(m, ev)
    if iso is not None:
        print(f"ISO 9283 on these poses (docs/report.md): AP max {iso['ap_mm']['max']:.4f} mm, mean "
              f"{iso['ap_mm']['mean']:.4f} mm; RP max {iso['rp_mm']['max']:.4f} mm, mean {iso['rp_mm']['mean']:.4f} mm "
              f"({iso['poses_with_repeats']} of {iso['poses']} poses measured 3 times or more)")
    if fitted.residual_model is not None:
        print("(errors of the physical model plus its non-physical residual stage, docs/residual-model.md)")
    for path in (args.json, args.residuals):
        if path:
            print(f"wrote {path}")
    if args.rrd or args.plots:
        from torchcal.cli._progress import progress
        from torchcal.cli._viz import evaluation_outputs
        with progress("evaluate", "drawing figures"):
            evaluation_outputs(args, model, m, ev)
    return 0
