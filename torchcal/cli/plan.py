"""`torchcal plan --robot R [--effects SPEC ...] --n N --out POSES.csv`: choose N measurement
poses from M candidates (Latin hypercube inside the joint limits, filtered like the sweep's
workspace) that best determine the identifiable parameters of the model to be fitted
(criterion D, O1 or E on the parameter Jacobian), ordered so the joint moves stay short.

The plan file has the measurement CSV's pose and joint columns, ``pose,q1,...,qN`` (degrees, mm for a prismatic joint);
measure x, y, z (mm) at each row and add them as columns to get a measurement file for
`torchcal fit`. Prints the criterion and the observability indices O1-O5 of the plan
against random plans of the same size from the same candidates."""

from __future__ import annotations

from torchcal.cli._args import finite_float, add_force, add_robot, check_outputs, nonneg_float, plot_outputs, positive_int, robot_inputs, seed_int, share

PNGS = ("plan_poses.png", "plan_criterion.png")  # in the --plots folder


def add_parser(sub):
    p = sub.add_parser("plan", help="choose optimal measurement poses (CSV)", description=__doc__)
    add_robot(p)
    p.add_argument("--effects", nargs="*", default=[], metavar="SPEC", help="effects of the model to be fitted")
    p.add_argument("--n", type=positive_int, required=True, help="number of poses N to choose")
    p.add_argument("--candidates", type=positive_int, default=10_000, help="candidate poses M (default 10000)")
    p.add_argument("--criterion", choices=["D", "O1", "E"], default="D", help="design criterion (default D)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the candidates and random plans")
    p.add_argument("--payload", type=nonneg_float, help="payload kg at which load-driven effects are "
                   "evaluated (default: the rated payload)")
    p.add_argument("--temp", type=finite_float, default=20.0, help="temperature deg C for thermal effects (default 20)")
    p.add_argument("--floor", type=finite_float, default=0.0, help="workspace: TCP z above this, mm (default 0)")
    p.add_argument("--column-radius", type=nonneg_float, default=None, help="workspace: keep-out radius "
                   "about joint 1, mm (default 350 x the arm's stretch / the KR 1000's 3037 mm: 350 on the KR 1000, "
                   "132 on a UR5e; 0: no column)")
    p.add_argument("--column-height", type=finite_float, default=None, help="workspace: keep-out height above "
                   "joint 1's frame, mm (default 1100, scaled as the radius: 416 on a UR5e)")
    p.add_argument("--reach", type=share, default=0.95, help="workspace: the TCP within this share of the arm's "
                   "full stretch from the shoulder, in (0, 1] (default 0.95; 1: no limit)")
    p.add_argument("--random-plans", type=positive_int, default=20, help="random plans to compare with (default 20)")
    p.add_argument("--out", required=True, help="plan CSV to write")
    p.add_argument("--plots", help="write PNG figures into this folder")
    add_force(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from torchcal.errors import InputError
    from torchcal.io.files import atomic_write
    from torchcal.io.plan_csv import plan_csv
    from torchcal.planning.plan import OBSERVABILITY, plan
    from torchcal.robots.workspace import Workspace
    from torchcal.io.robot_file import robot as make_robot

    check_outputs([("--out", args.out), *plot_outputs(args.plots, PNGS)], args.force,
                  inputs=robot_inputs(args.robot))  # all before the work
    if args.n > args.candidates:
        raise InputError(f"--n {args.n} is more than --candidates {args.candidates}")
    from torchcal.cli._progress import progress

    with progress("plan", f"choosing {args.n} of {args.candidates} candidate poses"):
        res = plan(make_robot(args.robot), args.effects, n=args.n, candidates=args.candidates, criterion=args.criterion,
                   seed=args.seed, payload_kg=args.payload, temp_c=args.temp, random_plans=args.random_plans,
                   workspace=Workspace(args.floor, args.column_radius, args.column_height, args.reach))
    robot = make_robot(args.robot)
    atomic_write(args.out, plan_csv(res.q, robot).encode(), force=args.force)
    d = res.to_dict()
    print(f"plan {args.robot} + [{', '.join(d['effects']) or 'geometric only'}]: {d['n']} of {d['candidates']} "
          f"candidate poses, {d['identifiable']} identifiable parameters, criterion {d['criterion']}")
    r = d["random"]
    print(f"criterion {d['criterion']}: plan {d['value']:.6g}; random plans of {d['n']} (n={r['plans']}) "
          f"mean {r['mean']:.6g}, best {r['best']:.6g}")
    print("observability   plan        random mean  random min..max")
    for k in OBSERVABILITY:
        o = d["observability"][k]
        print(f"  {k}            {o['plan']:<11.4g} {o['random_mean']:<12.4g} "
              f"{o['random_min']:.4g}..{o['random_max']:.4g}")
    if d["held"]:
        print(f"held at nominal (no candidate pose tells them from the parameters kept; fit holds them too): "
              f"{', '.join(d['held'])}")
    t = d["travel_deg"]
    print(f"joint travel (sum of largest joint move, from home): {t['ordered']:.0f} deg "
          f"ordered vs {t['selection']:.0f} deg in selection order")
    print(f"wrote {args.out} (pose,q1..q{res.q.shape[1]} in degrees, mm for a prismatic joint; measure x,y,z in mm "
          f"at each row)")
    if args.plots:
        from viz import planning as vp

        with progress("plan", "drawing figures"):
            vp.plan_poses(Path(args.plots) / PNGS[0], robot.fk(res.candidates), robot.fk(res.q), force=args.force)
            vp.criterion_vs_n(Path(args.plots) / PNGS[1], list(range(1, args.n + 1)), res.history,
                              res.random_curve(), args.criterion, force=args.force)
        for name in PNGS:
            print(f"wrote {Path(args.plots) / name}")
    return 0
