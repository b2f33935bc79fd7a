"""`torchcal accuracy MODEL.json [--n N] --plots DIR [--rrd FILE]`: the predicted TCP position
uncertainty of a calibrated model over the workspace.

At N workspace poses (Latin hypercube inside the joint limits, filtered like the sweep's
workspace) the parameter covariance stored in MODEL.json is propagated through the
position Jacobian: sigma = sqrt(trace J C J^T), the 1-sigma (RMS) length of the 3-D TCP
error that the parameter uncertainty leaves, in mm. Prints percentiles and the worst
regions (joint-1 sector x reach x height, tertiles), draws a map and a histogram, and
optionally a rerun recording. It covers what the fit could not determine, not what the
model leaves out (unmodelled effects add to it)."""

from __future__ import annotations

import torch

from torchcal.cli._args import add_force, check_outputs, nonneg_float, plot_outputs, positive_int

PNGS = ("accuracy_map.png", "accuracy_hist.png")  # in the --plots folder


def add_parser(sub):
    p = sub.add_parser("accuracy", help="predicted TCP sigma of a fitted model over the workspace",
                       description=__doc__)
    p.add_argument("model", help="MODEL.json from `torchcal fit`")
    p.add_argument("--n", type=positive_int, default=2000, help="workspace poses N (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the workspace sample")
    p.add_argument("--payload", type=nonneg_float, help="payload kg for load-driven effects (default: rated / 2)")
    p.add_argument("--temp", type=float, default=20.0, help="temperature deg C for thermal effects (default 20)")
    p.add_argument("--plots", help="write PNG figures into this folder")
    p.add_argument("--rrd", help="write a rerun recording (.rrd) here")
    add_force(p)
    p.set_defaults(func=run)


def region_names(robot, q: torch.Tensor, pos: torch.Tensor) -> list[str]:
    """'<sector> / <near|mid|far> / <low|mid|high>' per pose: joint-1 angle in four
    sectors (front -45..45 deg, left, back, right), reach from the joint-1 axis and height
    by tertiles of the sample."""
    a = torch.rad2deg(q[:, 0])
    sector = ["front" if abs(v) <= 45 else "left" if 45 < v <= 135 else "right" if -135 <= v < -45
              else "back" for v in a.tolist()]
    def tert(x, names):
        lo, hi = torch.quantile(x, torch.tensor([1 / 3, 2 / 3], dtype=x.dtype)).tolist()
        return [names[0] if v < lo else names[1] if v < hi else names[2] for v in x.tolist()]
    reach = tert(pos[:, :2].norm(dim=-1), ("near", "mid-reach", "far"))
    height = tert(pos[:, 2], ("low", "mid-height", "high"))
    return [f"{s} / {r} / {h}" for s, r, h in zip(sector, reach, height)]


def predicted_sigma(model, theta, cov, q, payload_kg=None, temp_c=None) -> torch.Tensor:
    """(N,) mm predicted TCP sigma at poses q (N, n) rad (Jacobian at theta)."""
    from torchcal.calibration.covariance import tcp_sigma
    from torchcal.effects import make_context

    ctx = make_context(model.robot, q, payload_kg, temp_c)
    return tcp_sigma(model.jacobian(theta, ctx), cov)


def run(args) -> int:
    from pathlib import Path

    from torchcal.io import modelfile
    from torchcal.effects import make_context
    from torchcal.reliability.sweep import sample_workspace

    check_outputs([("--rrd", args.rrd), *plot_outputs(args.plots, PNGS)], args.force,
                  inputs=[args.model])  # all before the work
    fitted = modelfile.load(args.model)
    model, theta = fitted.model, fitted.theta
    cov = modelfile.load_covariance(args.model, model)
    robot = model.robot
    q = sample_workspace(robot, args.n, seed=args.seed)
    N = q.shape[0]
    payload = torch.full((N,), robot.payload_kg / 2 if args.payload is None else args.payload, dtype=torch.float64)
    temp = torch.full((N,), args.temp, dtype=torch.float64)
    sigma = predicted_sigma(model, theta, cov, q, payload, temp)
    pos = model.predict(theta, make_context(robot, q, payload, temp))
    pct = torch.quantile(sigma, torch.tensor([0.5, 0.95], dtype=sigma.dtype)).tolist()
    print(f"accuracy of {args.model} ({robot.name} + [{', '.join(model.specs()) or 'geometric only'}]) "
          f"at {N} workspace poses: predicted TCP sigma (1-sigma, 3-D, mm) "
          f"min {float(sigma.min()):.4f}, median {pct[0]:.4f}, 95th percentile {pct[1]:.4f}, "
          f"max {float(sigma.max()):.4f}")
    names = region_names(robot, q, pos)
    groups = {}
    for nm, s in zip(names, sigma.tolist()):
        groups.setdefault(nm, []).append(s)
    rows = sorted(((sum(v) / len(v), max(v), len(v), k) for k, v in groups.items() if len(v) >= 5), reverse=True)
    print("worst regions (joint-1 sector / reach / height; mean sigma mm, max, points):")
    for mean, mx, n, k in rows[:3]:
        print(f"  {k:<32} {mean:.4f}  {mx:.4f}  {n}")
    if args.plots:
        from viz import planning as vp

        vp.accuracy_map(Path(args.plots) / PNGS[0], pos, sigma, force=args.force)
        vp.accuracy_histogram(Path(args.plots) / PNGS[1], sigma, force=args.force)
        print(f"wrote {args.plots}/accuracy_map.png, accuracy_hist.png")
    if args.rrd:
        from viz import planning as vp

        vp.log_accuracy(args.rrd, pos, sigma, seed=args.seed, force=args.force)
        print(f"wrote {args.rrd}")
    return 0
