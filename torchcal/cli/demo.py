"""`torchcal demo [--seeds [K]] [--json OUT] [--seed S] [--force]`: the paper's pipeline as a fair
experiment on a simulated KR 1000 Titan (torchcal.workflows.paper_experiment, docs/demo.md): sweep and
reliability map (Table 3), partition into levels and zones, the paper's per-zone calibration
(Table 4), fresh test points (Table 5), and the methods side by side (the paper, global
geometric, global with the effects `discover` finds, and that plus per-zone correction).

Without ``--seeds`` one seed runs; ``--seeds`` alone runs 10, ``--seeds K`` K seeds
(S .. S + K - 1): figures as mean and 95 % CI over seeds and a paired test of partitioned
vs global. Prints the report on stdout (torchcal.cli._report; progress on stderr).
``--json OUT`` writes `DemoRun.to_json`. The same seeds give the same numbers. Several seeds
run side by side on the cores (one process each, TORCHCAL_THREADS of them at most).
"""

from __future__ import annotations

import sys

from torchcal.cli._args import add_device, add_force, add_viz, check_outputs, device_of, seed_int


def add_parser(sub):
    p = sub.add_parser("demo", help="the paper's whole pipeline on a simulated KR 1000 Titan",
                       description=__doc__.splitlines()[0])
    p.add_argument("--json", help="write the report (JSON) here")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of every random draw (default 0)")
    p.add_argument("--seeds", type=int, nargs="?", const=10, default=1, metavar="K",
                   help="run seeds S .. S+K-1 (default: 1 seed; --seeds alone: 10)")
    p.add_argument("--discover-rounds", type=int, default=2, metavar="R",
                   help="effects `discover` may add for methods 3 and 4 (default 2; 0 skips discovery, "
                        "then methods 3 and 4 fit geometry + frame only)")
    add_force(p)
    add_device(p, "the workspace sweep")
    add_viz_options(p)
    p.set_defaults(func=run)
    return p


# -- hook for the figures and recordings (--rrd / --plots) ------------------------------
def add_viz_options(p) -> None:
    """Options of the visual outputs. Hook: add ``--rrd`` / ``--plots`` here
    (`torchcal.cli._args.add_viz`); `viz_outputs` then calls
    ``torchcal.cli._viz.demo_outputs(args, result)`` when either is given."""
    add_viz(p)


def viz_outputs(args, result) -> None:
    """Write the visual outputs of a finished demo (`result`: `DemoRun`; its first seed is drawn)."""
    if getattr(args, "rrd", None) or getattr(args, "plots", None):
        from torchcal.cli._viz import demo_outputs

        demo_outputs(args, result)


def _viz_outputs_to_check(args) -> list:
    return [("--rrd", getattr(args, "rrd", None))]


def run(args) -> int:
    from tqdm import tqdm

    from torchcal.cli._report import format_report
    from torchcal import threads
    from torchcal.errors import InputError
    from torchcal.io.files import write_json
    from torchcal.workflows.paper_config import DemoConfig
    from torchcal.workflows.paper_experiment import run_demo

    device = device_of(args)  # a refused --device before any work
    if args.seeds < 1:
        raise InputError(f"--seeds: expected a positive number of seeds, got {args.seeds}")
    if args.discover_rounds < 0:
        raise InputError(f"--discover-rounds: expected an integer >= 0, got {args.discover_rounds}")
    check_outputs([("--json", args.json), *_viz_outputs_to_check(args)], args.force)
    if args.rrd or args.plots:  # the PNG names too, before the run
        from torchcal.cli._viz import check_outputs as check_visual_outputs
        check_visual_outputs(args, "demo")
    # percent of the work done (steps weighed by their share of the time); only on a terminal
    with tqdm(total=100, desc="demo", unit="%", file=sys.stderr, leave=False, dynamic_ncols=True, disable=None,
              bar_format="{l_bar}{bar}| {elapsed}<{remaining}{postfix}") as bar:
        def progress(step, done):
            bar.set_postfix_str(step, refresh=False)
            bar.update(round(100 * done, 1) - bar.n)
        result = run_demo(DemoConfig(seed=args.seed, discover_rounds=args.discover_rounds), seeds=args.seeds,
                          progress=progress, device=device, processes=threads.workers())
    print(format_report(result))
    if args.json:
        write_json(args.json, result.to_json(), force=args.force)
        print(f"wrote {args.json}")
    viz_outputs(args, result)
    return 0
