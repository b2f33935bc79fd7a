"""`torchcal plan --robot R [--effects SPEC ...] --n N --out POSES.csv`: choose N measurement
poses from M candidates (Latin hypercube inside the joint limits, filtered like the sweep's
workspace) that best determine the identifiable parameters of the model to be fitted
(criterion D, O1 or E on the parameter Jacobian), ordered so the joint moves stay short.

The plan file has the measurement CSV's pose and joint columns, ``pose,q1,...,qN`` (degrees);
measure x, y, z (mm) at each row and add them as columns to get a measurement file for
`torchcal fit`. Prints the criterion and the observability indices O1-O5 of the plan
against random plans of the same size from the same candidates."""

from __future__ import annotations

import torch

from torchcal.cli._args import add_force, add_robot, check_outputs, nonneg_float, plot_outputs, positive_int

PNGS = ("plan_poses.png", "plan_criterion.png")  # in the --plots folder


def add_parser(sub):
    p = sub.add_parser("plan", help="choose optimal measurement poses (CSV)", description=__doc__)
    add_robot(p)
    p.add_argument("--effects", nargs="*", default=[], metavar="SPEC", help="effects of the model to be fitted")
    p.add_argument("--n", type=positive_int, required=True, help="number of poses N to choose")
    p.add_argument("--candidates", type=positive_int, default=10_000, help="candidate poses M (default 10000)")
    p.add_argument("--criterion", choices=["D", "O1", "E"], default="D", help="design criterion (default D)")
    p.add_argument("--seed", type=int, default=0, help="seed of the candidates and random plans")
    p.add_argument("--payload", type=nonneg_float, help="payload kg at which load-driven effects are "
                   "evaluated (default: the rated payload)")
    p.add_argument("--temp", type=float, default=20.0, help="temperature deg C for thermal effects (default 20)")
    p.add_argument("--floor", type=float, default=0.0, help="workspace: TCP z above this, mm (default 0)")
    p.add_argument("--column-radius", type=nonneg_float, default=350.0, help="workspace: keep-out radius "
                   "about joint 1, mm (default 350)")
    p.add_argument("--column-height", type=float, default=1100.0, help="workspace: keep-out height, mm (default 1100)")
    p.add_argument("--reach", type=nonneg_float, default=0.95, help="workspace: share of full stretch (default 0.95)")
    p.add_argument("--random-plans", type=positive_int, default=20, help="random plans to compare with (default 20)")
    p.add_argument("--out", required=True, help="plan CSV to write")
    p.add_argument("--plots", help="write PNG figures into this folder")
    add_force(p)
    p.set_defaults(func=run)


def plan_csv(q_rad: torch.Tensor) -> str:
    """CSV text `pose,q1..qN` in degrees for rows q (N, n) rad."""
    n = q_rad.shape[1]
    lines = ["pose," + ",".join(f"q{j + 1}" for j in range(n))]
    for i, row in enumerate(torch.rad2deg(q_rad).tolist()):
        lines.append(f"{i}," + ",".join(repr(round(v, 9)) for v in row))
    return "\n".join(lines) + "\n"


def run(args) -> int:
    from pathlib import Path

    from torchcal.calibration.model import CalibrationModel
    from torchcal.effects.spec import parse_specs
    from torchcal.errors import InputError
    from torchcal.io.files import atomic_write
    from torchcal.planning import design
    from torchcal.planning.order import order_poses, path_length
    from torchcal.reliability.sweep import Workspace, sample_workspace
    from torchcal.robots.robot import robot as make_robot

    check_outputs([("--out", args.out), *plot_outputs(args.plots, PNGS)], args.force)  # all before the work
    robot = make_robot(args.robot)
    specs = [str(s) for s in parse_specs(args.effects, robot.n)] if args.effects else []
    model = CalibrationModel(robot, specs)
    if args.n > args.candidates:
        raise InputError(f"--n {args.n} is more than --candidates {args.candidates}")
    ws = Workspace(args.floor, args.column_radius, args.column_height, args.reach)
    q = sample_workspace(robot, args.candidates, seed=args.seed, workspace=ws)
    M = q.shape[0]
    payload = torch.full((M,), robot.payload_kg if args.payload is None else args.payload, dtype=torch.float64)
    temp = torch.full((M,), args.temp, dtype=torch.float64)
    J = design.candidate_jacobian(model, q, payload, temp)
    free, A = design.scaled_columns(J, model)
    K = int(free.sum())
    if 3 * args.n < K:
        raise InputError(f"--n {args.n}: {3 * args.n} equations cannot determine the {K} identifiable "
                         f"parameters; need --n {-(-K // 3)} or more")
    plan = design.select(A, args.n, args.criterion)
    idx = plan.index[order_poses(q[plan.index])]
    gen = torch.Generator().manual_seed(args.seed + 1)
    rand = [torch.randperm(M, generator=gen)[: args.n] for _ in range(args.random_plans)]
    crit_r = torch.tensor([design.criterion(A[r], args.criterion) for r in rand])
    obs_p = design.observability(J[idx], model, free)
    obs_r = [design.observability(J[r], model, free) for r in rand]
    text = plan_csv(q[idx])
    atomic_write(args.out, text.encode(), force=args.force)
    names = ", ".join(specs) or "geometric only"
    print(f"plan {args.robot} + [{names}]: {args.n} of {M} candidate poses, {K} identifiable parameters, "
          f"criterion {args.criterion}")
    print(f"criterion {args.criterion}: plan {plan.value:.6g}; random plans of {args.n} (n={len(rand)}) "
          f"mean {float(crit_r.mean()):.6g}, best {float(crit_r.max()):.6g}")
    print("observability   plan        random mean  random min..max")
    for k in ("O1", "O2", "O3", "O4", "O5"):
        v = torch.tensor([o[k] for o in obs_r])
        print(f"  {k}            {obs_p[k]:<11.4g} {float(v.mean()):<12.4g} "
              f"{float(v.min()):.4g}..{float(v.max()):.4g}")
    held = [n for n, f, c in zip(model.param_names(), free.tolist(), model.default_free().tolist()) if c and not f]
    if held:
        print(f"not identifiable from any pose (held at nominal): {', '.join(held)}")
    z = torch.zeros(robot.n, dtype=torch.float64)
    print(f"joint travel (sum of largest joint move, from home): {path_length(q[idx], z) * 57.29577951308232:.0f} deg "
          f"ordered vs {path_length(q[plan.index], z) * 57.29577951308232:.0f} deg in selection order")
    print(f"wrote {args.out} (pose,q1..q{robot.n} in degrees; measure x,y,z in mm at each row)")
    if args.plots:
        from viz import planning as vp

        pos = robot.fk(q)
        vp.plan_poses(Path(args.plots) / PNGS[0], pos, pos[idx], force=args.force)
        ns = list(range(1, args.n + 1))
        rand_curve = []
        for k in ns:
            if 3 * k < K:
                rand_curve.append(None)
                continue
            vals = [design.criterion(A[torch.randperm(M, generator=gen)[:k]], args.criterion) for _ in range(5)]
            rand_curve.append(sum(vals) / len(vals))
        vp.criterion_vs_n(Path(args.plots) / PNGS[1], ns, plan.history, rand_curve,
                          args.criterion, force=args.force)
        print(f"wrote {args.plots}/plan_poses.png, plan_criterion.png")
    return 0
