"""The real UR10 series over five splits, through the command line as a user runs it.

For each series (B, C, D of examples/ur10) and split seed (60/40 by pose, seeds 0-4):

1. ``fit --effects base_frame tool_offset`` on the training poses, ``evaluate`` on the
   validation poses;
2. ``discover`` (same start), ``evaluate`` of its final model;
3. ``fit`` of the discovered effects with the residual stage, ``evaluate``;
4. what the probe leaves on held-out poses (``unexplained.probe_left_rms_mm`` of discover's report).

Prints one line per run, a table of means and standard deviations (mm, validation RMS of
the distance error) and a table of the held-out distance error's mean, RMS, 95th
percentile and maximum (each the mean over the splits) against the targets, and writes
every figure to ``--json``, each split's `discover` history (the JSON of ``discover
--json``: every round's refitted candidates, figures and reasons) under its row's
"discover_history". Wall times are of whole commands (start-up included).

Usage: python benchmarks/study_real.py [--series b c d] [--seeds 0 1 2 3 4] [--json OUT]
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
UR10 = ROOT / "examples" / "ur10"
START = ["base_frame", "tool_offset"]


def torchcal(*args) -> float:
    """Run `python -m torchcal ARGS`; return its wall time in s (raises on failure)."""
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "torchcal", *map(str, args)], capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"torchcal {' '.join(map(str, args))} failed:\n{r.stderr}")
    return time.perf_counter() - t


#: held-out RMS targets (mm) with named physical effects (discover), and with the residual stage
TARGETS = {"b": (0.32, None), "c": (0.30, 0.20), "d": (0.32, None)}
STATS = ("mean", "rms", "p95", "max")


def val_stats(model: Path, val: Path, work: Path) -> dict:
    """mean, rms, p95, max (mm) of the held-out distance errors of `model` on `val`."""
    out = work / f"eval_{model.stem}.csv"
    torchcal("evaluate", val, "--model", model, "--residuals", out, "--force")
    with out.open() as f:
        e = [float(row["e_mm"]) for row in csv.DictReader(f)]
    e.sort()
    p95 = e[min(len(e) - 1, max(0, round(0.95 * len(e)) - 1))]
    return {"mean": statistics.fmean(e), "rms": statistics.fmean(x * x for x in e) ** 0.5, "p95": p95,
            "max": e[-1]}


def one(series: str, seed: int, work: Path) -> dict:
    tr, va = work / "train.csv", work / "val.csv"
    robot = UR10 / "ur10.json"
    torchcal("split", UR10 / f"series_{series}.csv", "--robot", robot, "--fraction", "0.6", "--seed", seed,
             "--out", tr, va, "--force")
    row = {"series": series, "seed": seed}
    row["fit_s"] = torchcal("fit", tr, "--robot", robot, "--effects", *START, "--out", work / "fit.json", "--force")
    row["fit_stats"] = val_stats(work / "fit.json", va, work)
    row["fit"] = row["fit_stats"]["rms"]
    row["discover_s"] = torchcal("discover", tr, "--robot", robot, "--effects", *START, "--out", work / "disc.json",
                                 "--json", work / "hist.json", "--force")
    row["discover_stats"] = val_stats(work / "disc.json", va, work)
    row["discover"] = row["discover_stats"]["rms"]
    hist = json.loads((work / "hist.json").read_text())
    row["discover_history"] = hist
    found = json.loads((work / "disc.json").read_text())["effects"]
    row["effects"] = [e if isinstance(e, str) else e.get("spec", str(e)) for e in found]
    row["learnable"] = (hist.get("unexplained") or {}).get("probe_left_rms_mm")
    torchcal("fit", tr, "--robot", robot, "--effects", *row["effects"], "--residual-model", "kernel",
             "--out", work / "resid.json", "--force")
    row["residual_stats"] = val_stats(work / "resid.json", va, work)
    row["residual"] = row["residual_stats"]["rms"]
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--series", nargs="+", default=["b", "c", "d"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    ap.add_argument("--json", help="write every figure here")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in args.series:
            for seed in args.seeds:
                r = one(s, seed, Path(tmp))
                rows.append(r)
                print(f"series {s} seed {seed}: fit {r['fit']:.4f}  discover {r['discover']:.4f} "
                      f"[{', '.join(r['effects'])}]  + residual {r['residual']:.4f}  learnable "
                      f"{r['learnable'] if r['learnable'] is None else round(r['learnable'], 4)}  "
                      f"(fit {r['fit_s']:.1f} s, discover {r['discover_s']:.1f} s)", flush=True)
                if args.json:  # after every run: a study cut short keeps what it measured
                    Path(args.json).write_text(json.dumps(rows, indent=1))
    print("\n| series | fit | discover | discover + residual | probe learnable | discover worse than fit | discover wall s |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for s in args.series:
        rs = [r for r in rows if r["series"] == s]

        def ms(key, rs=rs):
            v = [r[key] for r in rs if r[key] is not None]
            if not v:
                return "-"
            return f"{statistics.mean(v):.4f} ± {statistics.stdev(v):.4f}" if len(v) > 1 else f"{v[0]:.4f}"

        worse = sum(r["discover"] > r["fit"] for r in rs)
        walls = sorted(r["discover_s"] for r in rs)
        print(f"| {s.upper()} | {ms('fit')} | {ms('discover')} | {ms('residual')} | {ms('learnable')} | "
              f"{worse} of {len(rs)} | median {statistics.median(walls):.1f} |")
    print("\nHeld-out distance error (mm), each figure the mean over the splits:\n")
    print("| series | model | mean | RMS | p95 | max | target (RMS) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for s in args.series:
        rs = [r for r in rows if r["series"] == s]
        for key, label, target in (("fit", "fit", None), ("discover", "discover", TARGETS.get(s, (None,))[0]),
                                   ("residual", "discover + residual stage", TARGETS.get(s, (None, None))[1])):
            figs = " | ".join(f"{statistics.mean(r[key + '_stats'][k] for r in rs):.4f}" for k in STATS)
            print(f"| {s.upper()} | {label} | {figs} | {'-' if target is None else f'<= {target:.2f}'} |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
