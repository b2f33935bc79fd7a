"""`torchcal sweep`: reliability of positioning over the workspace (docs/paper.md section 6).

    torchcal sweep --robot kr1000titan --n 100 --samples 300 --allowed 2.5 --seed 0 --out sweep.csv

Samples N workspace points (Latin hypercube in joint space, filtered), M clearance states
of the robot's `ClearanceModel`, and writes one CSV row per point. The clearance model:
``--clearance FILE.json`` if given, else the robot file's "clearance" section, else (the
kr1000titan preset only) docs/paper.md Table 2; both take {"radii_mm": [2n],
"clearance_mm": [2n], "bearing_length_mm": [n]} (mm, docs/robots.md). Any joint count,
revolute and prismatic joints (q in mm in the CSV for a prismatic joint).


    # torchcal-sweep/2 {"made_for": {"name", "fingerprint", "nominal_robot"}}
    point,q1..qN,x,y,z,ex_lo,ex_hi,ey_lo,ey_hi,ez_lo,ez_hi,dist_lo,dist_hi,eta,r_set

The first line records the robot the sweep was made for (`torchcal.io.robot_file.robot_record`:
its name and the fingerprint of its nominal kinematics and joint limits, docs/formats.md),
which `torchcal partition` copies and `torchcal calibrate` checks. ``point`` is the 0-based row index, q in degrees (mm: prismatic), x y z the nominal TCP position (mm),
e* the error interval per axis and dist_* the distance-error interval (mm), eta (eq. 23)
and r_set (eq. 24) against the allowed distance error [0, --allowed] mm. Prints a short
summary (R_set min / median / max, share of points with R_set = 1) on stdout.

``--bounds sampled`` (default, the paper's) bounds the error by its extremes over the M
sampled states, which lie under the largest error the clearance allows (21-31 % at the
median point with M = 300, docs/scale.md). ``--bounds worst`` bounds it over the whole
clearance set, to first order (`torchcal.reliability.worst_case`): per axis the exact range,
dist_hi the largest |e| found by coordinate ascent from the best sampled state (never below
the sampled bound), and a column dist_hi_outer after dist_hi, a guaranteed first-order upper
bound (triangle inequality): the worst case lies in [dist_hi, dist_hi_outer]. eta and r_set
are then those of these bounds.

The points are computed in blocks of --block points (each drawn from its own seed), written
block by block into OUT.blocks/ and copied into OUT when all are done: an interrupted run
started again with the same arguments computes only the missing blocks (and says so); with
other arguments it refuses unless --force. ``--workers N`` computes the blocks on N threads
of this process (no cluster), ``--scheduler ADDRESS`` on an existing Dask cluster (the extra
``pip install 'torchcal[distributed]'``, docs/scale.md); the CSV is the same in every case.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from torchcal.cli._args import add_device, add_force, check_outputs, device_of, positive_int, positive_float, add_robot, seed_int


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("sweep", help="error envelopes and R_set over the workspace (CSV)",
                       description=__doc__.splitlines()[0])
    add_robot(p, required=False, default="kr1000titan")
    p.add_argument("--n", type=positive_int, default=100, help="workspace points N (default 100)")
    p.add_argument("--samples", type=positive_int, default=300,
                   help="clearance states M per point (default 300)")
    p.add_argument("--allowed", type=positive_float, default=2.5,
                   help="allowed distance error D in mm: R_set against [0, D] (default 2.5)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the Latin hypercube and the states")
    p.add_argument("--bounds", choices=["sampled", "worst"], default="sampled",
                   help="sampled: extremes over the M states (the paper's, default); worst: over the whole "
                        "clearance set (coordinate ascent, with a first-order outer bound column dist_hi_outer)")
    p.add_argument("--clearance", metavar="FILE.json",
                   help="joint-clearance model {radii_mm, clearance_mm, bearing_length_mm} (mm); "
                        "default: the robot file's \"clearance\" section, or Table 2 for kr1000titan")
    p.add_argument("--block", type=positive_int, default=None, metavar="POINTS",
                   help="points per block (default 20000): the unit of seeding, of the cluster's "
                        "tasks and of the resumable output; the result depends on it")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="run the blocks on the Dask cluster of this scheduler (tcp://host:8786)")
    where.add_argument("--workers", type=positive_int, metavar="N",
                       help="N worker threads in this process (default: TORCHCAL_THREADS or the cores; no cluster)")
    p.add_argument("--out", required=True, help="output CSV")
    add_device(p, "the blocks run (in this process)")
    add_force(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    import torchcal
    from torchcal.io.files import read_json
    from torchcal.workflows.distributed import connect, plan_sweep, run_sweep
    from torchcal.reliability.sweep_blocks import DEFAULT_BLOCK
    from torchcal.reliability.sweep import warn_samples
    from torchcal.reliability.uncertainty import ClearanceModel, clearance_from_dict

    from torchcal.errors import InputError

    device = device_of(args)
    if device.type != "cpu" and (args.workers or args.scheduler):
        raise InputError(f"--device {args.device} computes the blocks on the GPU of this process; "
                         f"drop --workers / --scheduler (or use --device cpu)")
    check_outputs([("--out", args.out)], args.force)  # fail before the work, not after it
    out = Path(args.out)
    robot = torchcal.robot(args.robot)
    model = (clearance_from_dict(read_json(args.clearance, "clearance file"), args.clearance, robot.n)
             if args.clearance else ClearanceModel.defaults(robot))
    plan = plan_sweep(robot, n_points=args.n, n_samples=args.samples, allowed_mm=args.allowed, seed=args.seed,
                      model=model, block=args.block or DEFAULT_BLOCK, bounds=args.bounds)
    warn_samples(args.samples)  # the bounds of a few states fall far short (MIN_SAMPLES); after any refusal
    with connect(scheduler=args.scheduler) as client:
        s = run_sweep(plan, out, client=client, threads=args.workers, device=device, force=args.force,
                      progress=not args.no_progress, log=print)
    n1 = round(s["share_r_set_1"] * s["points"])
    how = "" if args.bounds == "sampled" else ", worst-case bounds over the clearance set"
    print(f"sweep: {s['points']} points x {args.samples} clearance states{how}, allowed distance error "
          f"[0, {args.allowed:g}] mm -> {out}")
    print(f"R_set min {s['r_set_min']:.3f}  median {s['r_set_median']:.3f}  max {s['r_set_max']:.3f}  "
          f"R_set = 1 at {100 * s['share_r_set_1']:.1f}% of the points ({n1}/{s['points']})")
    print(f"distance error upper bound {s['dist_upper_min_mm']:.3f} .. {s['dist_upper_max_mm']:.3f} mm; "
          f"{'sampled' if args.bounds == 'sampled' else 'worst-case'} / linearised half-width, median {s['linear_ratio_median']:.2f} "
          f"(max {s['linear_ratio_max']:.2f})")
    return 0
