"""`torchcal accuracy MODEL.json [--n N] [--range calibrated|limits] [--plots DIR] [--rrd FILE]`: the predicted TCP position
uncertainty of a calibrated model over the workspace.

At N workspace poses (Latin hypercube inside the joint range the model was calibrated on,
``--range limits``: inside the joint limits, where the model extrapolates beyond that
range; filtered like the sweep's workspace) the parameter covariance stored in MODEL.json
is propagated through the
position Jacobian: sigma = sqrt(trace J C J^T), the 1-sigma (RMS) length of the 3-D TCP
error that the parameter uncertainty leaves, in mm. Prints percentiles and the worst
regions (joint-1 sector x reach x height, tertiles), draws a map and a histogram, and
optionally a rerun recording. It covers what the fit could not determine, not what the
model leaves out (unmodelled effects add to it)."""

from __future__ import annotations

from torchcal.cli._args import finite_float, add_force, check_outputs, nonneg_float, plot_outputs, positive_int, seed_int

PNGS = ("accuracy_map.png", "accuracy_hist.png")  # in the --plots folder


def add_parser(sub):
    p = sub.add_parser("accuracy", help="predicted TCP sigma of a fitted model over the workspace",
                       description=__doc__)
    p.add_argument("model", help="MODEL.json from `torchcal fit`")
    p.add_argument("--n", type=positive_int, default=2000, help="workspace poses N (default 2000)")
    p.add_argument("--range", choices=("calibrated", "limits"), default="calibrated", dest="within",
                   help="draw the poses inside the joint range the model was calibrated on (default) or inside "
                        "the joint limits (the model extrapolates beyond its calibrated range)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the workspace sample")
    p.add_argument("--payload", type=nonneg_float, help="payload kg for load-driven effects (default: rated / 2)")
    p.add_argument("--temp", type=finite_float, default=20.0, help="temperature deg C for thermal effects (default 20)")
    p.add_argument("--plots", help="write PNG figures into this folder")
    p.add_argument("--rrd", help="write a rerun recording (.rrd) here")
    add_force(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from torchcal.api import accuracy

    check_outputs([("--rrd", args.rrd), *plot_outputs(args.plots, PNGS)], args.force,
                  inputs=[args.model])  # all before the work
    from torchcal.calibration.accuracy import ZoneAccuracyWarning
    from torchcal.cli._args import warnings_to_stderr

    with warnings_to_stderr(ZoneAccuracyWarning):  # independent zones: the figures are the global fit's
        acc = accuracy(args.model, n=args.n, seed=args.seed, payload_kg=args.payload, temp_c=args.temp,
                       within=args.within)
    d = acc.to_dict()
    s = d["sigma_mm"]
    if acc.q_range is None:
        where = "inside the joint limits (the model records no calibrated joint range)"
    elif d["within"] == "calibrated":
        where = "inside the joint range the model was calibrated on"
    else:
        where = (f"inside the joint limits, {d['outside_calibrated_range']} of them beyond the joint range the "
                 f"model was calibrated on (it extrapolates there)")
    tcp = (f"predicted sigma of the worst of its {len(acc.points)} reflectors at each pose" if acc.points
           else "predicted TCP sigma")
    print(f"accuracy of {args.model} ({d['robot']} + [{', '.join(d['effects']) or 'geometric only'}]) "
          f"at {d['poses']} workspace poses {where}: {tcp} (1-sigma, 3-D, mm) "
          f"min {s['min']:.4f}, median {s['median']:.4f}, 95th percentile {s['p95']:.4f}, max {s['max']:.4f}")
    print("worst regions (joint-1 sector / reach / height; mean sigma mm, max, points):")
    for r in d["regions"][:3]:
        print(f"  {r['region']:<32} {r['mean_mm']:.4f}  {r['max_mm']:.4f}  {r['points']}")
    if args.plots:
        from viz import planning as vp

        vp.accuracy_map(Path(args.plots) / PNGS[0], acc.pos, acc.sigma, force=args.force)
        vp.accuracy_histogram(Path(args.plots) / PNGS[1], acc.sigma, force=args.force)
        print(f"wrote {args.plots}/accuracy_map.png, accuracy_hist.png")
    if args.rrd:
        from viz import planning as vp

        vp.log_accuracy(args.rrd, acc.pos, acc.sigma, seed=args.seed, force=args.force)
        print(f"wrote {args.rrd}")
    return 0
