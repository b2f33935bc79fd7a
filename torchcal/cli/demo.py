"""`torchcal demo [--json OUT] [--seed S] [--force]`: the paper's whole pipeline on a simulated
KR 1000 Titan (torchcal.workflows.paper): sweep and reliability map (Table 3), partition into
levels and zones, per-zone interval calibration (Table 4), compensation of 20 test
points (Table 5), the reductions of the error bounds, and the same for one global
calibration, side by side.

Prints the tables on stdout (progress on stderr). ``--json OUT`` writes the report:
``zones``, ``seconds``, ``reduction_percent``, ``test_points`` (zone, error intervals before
and after, R_set after), ``partitioned`` / ``global`` (test RMS, reductions) and more (see
`PipelineResult.to_json`). Everything is seeded: the same seed gives the same numbers.
"""

from __future__ import annotations

import sys

from torchcal.cli._args import add_force, add_viz, check_outputs


def add_parser(sub):
    p = sub.add_parser("demo", help="the paper's whole pipeline on a simulated KR 1000 Titan",
                       description=__doc__.splitlines()[0])
    p.add_argument("--json", help="write the report (JSON) here")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")
    add_force(p)
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
    """Write the visual outputs of a finished demo (`result`: `PipelineResult`)."""
    if getattr(args, "rrd", None) or getattr(args, "plots", None):
        from torchcal.cli._viz import demo_outputs

        demo_outputs(args, result)


def _viz_outputs_to_check(args) -> list:
    return [("--rrd", getattr(args, "rrd", None))]


def run(args) -> int:
    from tqdm import tqdm

    from torchcal.io.files import write_json
    from torchcal.workflows.paper import DemoConfig, run_pipeline

    check_outputs([("--json", args.json), *_viz_outputs_to_check(args)], args.force)
    if args.rrd or args.plots:  # the PNG names too, before the run
        from torchcal.cli._viz import check_outputs as check_visual_outputs
        check_visual_outputs(args, "demo")
    steps = ["sweep", "partition", "calibrate", "test"]
    with tqdm(total=len(steps), desc="demo", unit="step", file=sys.stderr, leave=False,
              dynamic_ncols=True) as bar:
        def progress(step):
            bar.set_postfix_str(step)
            if step != steps[0]:
                bar.update(1)
        result = run_pipeline(DemoConfig(seed=args.seed), progress=progress)
        bar.update(1)
    print(result.format_report())
    if args.json:
        write_json(args.json, result.to_json(), force=args.force)
        print(f"wrote {args.json}")
    viz_outputs(args, result)
    return 0
