"""`torchcal discover DATA --robot R [--json OUT] [--out MODEL.json] [--rrd FILE]`: add the
best significant effect each round until none is left; the error falls at each round."""

from __future__ import annotations

from torchcal.cli._args import (add_cv, add_device, add_effects_module, add_force, add_units, add_viz, check_folder,
                                check_outputs, device_of, read_data, add_robot)
from torchcal.cli.diagnose import add_sigmas, print_step


def add_parser(sub):
    p = sub.add_parser("discover", help="add missing effects round by round", description=__doc__)
    p.add_argument("data", help="measurement CSV")
    add_robot(p)
    p.add_argument("--effects", nargs="*", default=[], metavar="SPEC", help="effects to start from")
    add_cv(p)
    add_sigmas(p)
    p.add_argument("--json", help="write the history here")
    p.add_argument("--out", help="write the final MODEL.json here")
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
    from torchcal.robots.robot import robot as make_robot

    device = device_of(args)  # a refused --device before any work
    check_outputs([("--json", args.json), ("--out", args.out), ("--rrd", args.rrd)], args.force,
                  inputs=[args.data])
    check_folder("--plots", args.plots)
    if args.rrd or args.plots:  # the PNG names too, before any work
        from torchcal.cli._viz import check_outputs as check_visual_outputs
        check_visual_outputs(args, "discover")
    robot = make_robot(args.robot).to(device)
    m = read_data(args.data, robot, args).to(device)
    res = api.discover(robot, m, args.effects, folds=args.folds, seed=args.seed, sigma_mm=args.sigma_mm,
                       sigma_deg=args.sigma_deg)
    for i, (h, d) in enumerate(zip(res.history, res.diagnoses)):
        print(f"round {i}:")
        print_step(d.step)
    print(f"final effects: {', '.join(res.final_effects) or 'none'}")
    if res.unexplained is not None:
        print(res.unexplained.describe())
    if args.json:
        write_json(args.json, res.to_dict(), force=args.force, inputs=[args.data])
    if args.out:
        write_json(args.out, modelfile.to_dict(res.fit, source=args.data, seed=args.seed,
                                               pose_ids=m.pose.tolist()),
                   force=args.force, inputs=[args.data])
    if args.rrd or args.plots:
        from torchcal.cli._viz import discovery_outputs
        discovery_outputs(args, robot, m, res)
    return 0
