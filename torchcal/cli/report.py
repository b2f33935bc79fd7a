"""`torchcal report MODEL.json [--data HELD_OUT.csv] [--history DISCOVER.json] [--tolerance-mm T]
--out REPORT.html`: a calibration report in one self-contained HTML file.

The file opens from a USB stick in any browser: CSS and figures (PNG) inside it, no script,
nothing fetched from a network; it prints on A4, one section per page. First page: the
model, the accuracy on the held-out poses before (the nominal robot in its best measuring
frame) and after (the calibrated model) as mean, RMS, p95 and max of the distance error,
ISO 9283 AP (and RP when poses are measured 3 times or more), and the verdict against
``--tolerance-mm``. Then the evidence: provenance (paths, SHA-256, dates, units, frames),
the model (effects and their physics, parameters with std and 95 % intervals, what is held),
the errors per axis, the error map and residual figures, the verdict per pose, discover's
rounds (every refitted candidate with its verdict and reason, from ``discover --json``),
what stays learnable, and the transfer check when the history holds one.

``--data`` should be poses the fit never saw (e.g. the validation part of
``examples/ur10/split.py``). ``--json OUT`` writes the report's figures as JSON too."""

from __future__ import annotations

from torchcal.cli._args import add_force, add_units, check_outputs, positive_float, read_data


def add_parser(sub):
    p = sub.add_parser("report", help="a self-contained HTML calibration report", description=__doc__)
    p.add_argument("model", help="MODEL.json from `torchcal fit` or `torchcal discover --out`")
    p.add_argument("--data", help="held-out measurement CSV (poses the fit never saw)")
    p.add_argument("--history", help="the --json of `torchcal discover` (its rounds and verdicts)")
    p.add_argument("--tolerance-mm", type=positive_float, help="distance tolerance in mm for the pass/fail verdict")
    p.add_argument("--out", required=True, help="REPORT.html to write")
    p.add_argument("--json", help="write the report's figures as JSON here too")
    add_units(p)
    add_force(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from torchcal.api import load
    from torchcal.io.files import write_json
    from torchcal.workflows.report import calibration_report
    from viz.report import write_report

    inputs = [args.model, args.data, args.history]
    check_outputs([("--out", args.out), ("--json", args.json)], args.force, inputs=inputs)
    data = None
    if args.data:
        data = read_data(args.data, load(args.model).model.robot, args)
    rep = calibration_report(args.model, data, history_path=args.history, tolerance_mm=args.tolerance_mm)
    write_report(args.out, rep, force=args.force, inputs=inputs)
    if args.json:
        write_json(args.json, rep.to_dict(), force=args.force, inputs=inputs)
    if rep.after is not None:
        a, b = rep.after, rep.before
        print(f"{a['n']} held-out rows: before (nominal) rms {b['rms_mm']:.4f} mm, p95 {b['p95_mm']:.4f} mm; after "
              f"mean {a['mean_mm']:.4f} mm, rms {a['rms_mm']:.4f} mm, p95 {a['p95_mm']:.4f} mm, "
              f"max {a['max_mm']:.4f} mm")
    v = rep.verdict_after
    if v is not None:
        print(f"verdict: {'PASS' if v['passed'] else 'FAIL'}, {v['poses'] - v['poses_failed']} of {v['poses']} poses "
              f"within {v['tolerance_mm']:g} mm")
    for p in [args.out] + ([args.json] if args.json else []):
        print(f"wrote {p}")
    return 0
