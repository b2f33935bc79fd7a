"""`torchcal partition`: hierarchical FCM partition of a sweep (docs/paper.md section 4).

    torchcal partition SWEEP.csv --levels 4 [--zones 3,2,3,2 | auto] [--seed S]
                       --out PARTITION.json [--force]

Reads the sweep CSV written by `torchcal sweep` (columns point,q1..qn,x,y,z,ex_lo,ex_hi,
ey_lo,ey_hi,ez_lo,ez_hi,dist_lo,dist_hi,eta,r_set; only point, x, y, z (mm) and r_set are
used, other columns are ignored), writes the partition JSON (`torchcal.io.partition_file`)
and prints one line per zone. The partition records the robot its sweep was made for (the
sweep's first line, copied), which `torchcal calibrate` checks against its --robot; a sweep
CSV of an older torchcal records none: a warning says so, and the partition records none.
"""

from __future__ import annotations

import sys
from pathlib import Path

from torchcal.cli._args import finite_float, add_force, check_outputs, seed_int
from torchcal.errors import InputError

NEEDED = ("point", "x", "y", "z", "r_set")


def add_parser(sub):
    p = sub.add_parser("partition", help="hierarchical fuzzy c-means partition of a sweep CSV",
                       description=__doc__.splitlines()[0])
    p.add_argument("sweep", metavar="SWEEP.csv", help="sweep CSV (point,q1..qn,x,y,z,...,eta,r_set)")
    p.add_argument("--levels", default="4", help="number of R_set levels (>= 2) or 'auto' (default 4)")
    p.add_argument("--zones", default="auto",
                   help="sub-zones per level, comma separated (paper: 3,2,3,2), or 'auto' (default); at most half a level's sweep points")
    p.add_argument("--zone-range", default="2,3", metavar="LO,HI",
                   help="sub-zone counts tried per level with --zones auto, best Xie-Beni (default 2,3)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the FCM random starts (default 0)")
    p.add_argument("--restarts", type=int, default=5, help="FCM random starts, best kept (default 5)")
    p.add_argument("--m", type=finite_float, default=2.0, help="FCM fuzzifier m > 1 (default 2)")
    p.add_argument("--r-weight", type=finite_float, default=1.0,
                   help="weight of standardised R_set against standardised x, y, z in the sub-zones (default 1)")
    p.add_argument("--out", required=True, metavar="PARTITION.json", help="output partition JSON")
    add_force(p)
    p.set_defaults(func=run)
    return p


def _levels(text):
    if text == "auto":
        return "auto"
    try:
        v = int(text)
    except ValueError:
        raise InputError(f"--levels: expected an integer >= 2 or 'auto', got {text!r}") from None
    if v < 2:
        raise InputError(f"--levels: expected an integer >= 2 or 'auto', got {text!r}")
    return v


def _zones(text, levels):
    if text == "auto":
        return "auto"
    try:
        ks = [int(t) for t in text.split(",")]
    except ValueError:
        raise InputError(f"--zones: expected comma separated integers (e.g. 3,2,3,2) or 'auto', got {text!r}") from None
    if any(k < 1 for k in ks):
        raise InputError(f"--zones: expected counts >= 1, got {text!r}")
    if levels != "auto" and len(ks) != levels:
        raise InputError(f"--zones: {len(ks)} counts for --levels {levels}; expected one count per level")
    return ks


def _range(text):
    try:
        lo, hi = (int(t) for t in text.split(","))
    except ValueError:
        raise InputError(f"--zone-range: expected LO,HI integers (e.g. 2,3), got {text!r}") from None
    if not 2 <= lo <= hi:
        raise InputError(f"--zone-range: expected 2 <= LO <= HI, got {text!r}")
    return lo, hi


def _check_numbers(args) -> None:
    """InputError naming the option (not the library argument) for --m, --restarts, --r-weight."""
    if not args.m > 1:
        raise InputError(f"--m: expected a fuzzifier m > 1, got {args.m!r}")
    if args.restarts < 1:
        raise InputError(f"--restarts: expected an integer >= 1, got {args.restarts!r}")
    if not args.r_weight >= 0:
        raise InputError(f"--r-weight: expected a finite weight >= 0, got {args.r_weight!r}")


def run(args) -> int:
    from torchcal.io.partition_file import save_partition
    from torchcal.io.sweep_csv import read_sweep, sweep_record
    from torchcal.partition.zones import partition_workspace

    levels = _levels(args.levels)
    zones = _zones(args.zones, levels)
    zone_range = _range(args.zone_range)
    _check_numbers(args)
    check_outputs([("--out", args.out)], args.force, inputs=[args.sweep])
    out = Path(args.out)
    record = sweep_record(args.sweep)  # the robot it was made for, copied into the partition
    sw = read_sweep(args.sweep)  # errors name the file, row and column
    if record is None:
        print(f"torchcal: warning: {args.sweep}: records no robot (a sweep CSV of an older torchcal): the "
              f"partition records none either, and calibrate cannot check it against its --robot", file=sys.stderr)
    ids, pos, r = sw.point, sw.positions, sw.r_set
    part = partition_workspace(pos, r, levels, zones, m=args.m, r_weight=args.r_weight, seed=args.seed,
                               restarts=args.restarts, zone_range=zone_range, point_ids=ids)
    save_partition(part, out, force=args.force, inputs=[args.sweep], made_for=record)
    print(f"{args.sweep}: {pos.shape[0]} points -> {part.n_levels} levels, {part.n_zones} zones -> {out}")
    print(f"{'zone':>4} {'level':>5} {'points':>6} {'R_set min':>9} {'mean':>7} {'max':>7} "
          f"{'centre x mm':>12} {'y mm':>10} {'z mm':>10}")
    for s in part.summary():
        print(f"{s['zone']:>4} {s['level']:>5} {s['points']:>6} {s['r_set_min']:>9.4f} {s['r_set_mean']:>7.4f} "
              f"{s['r_set_max']:>7.4f} {s['center_x_mm']:>12.2f} {s['center_y_mm']:>10.2f} {s['center_z_mm']:>10.2f}")
    print(f"wrote {out}")
    return 0
