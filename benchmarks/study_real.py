"""The real UR10 series over five splits, through the command line as a user runs it.

For each series (B, C, D of examples/ur10) and split seed (60/40 by pose, seeds 0-4):

1. ``fit --effects base_frame tool_offset`` on the training poses, ``evaluate`` on the
   validation poses;
2. ``discover`` (same start), ``evaluate`` of its final model;
3. ``fit`` of the discovered effects with the residual stage, ``evaluate``;
4. what the probe leaves on held-out poses (``unexplained.probe_left_rms_mm`` of discover's report).

Prints one line per run and a table of means and standard deviations (mm, validation
RMS of the distance error), and writes every figure to ``--json``. Wall times are of
whole commands (start-up included).

Usage: python benchmarks/study_real.py [--series b c d] [--seeds 0 1 2 3 4] [--json OUT]
"""

from __future__ import annotations

import argparse
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


def val_rms(model: Path, val: Path, work: Path) -> float:
    out = work / f"eval_{model.stem}.json"
    torchcal("evaluate", val, "--model", model, "--json", out, "--force")
    return json.loads(out.read_text())["rms_mm"]


def one(series: str, seed: int, work: Path) -> dict:
    tr, va = work / "train.csv", work / "val.csv"
    robot = UR10 / "ur10.json"
    torchcal("split", UR10 / f"series_{series}.csv", "--robot", robot, "--fraction", "0.6", "--seed", seed,
             "--out", tr, va, "--force")
    row = {"series": series, "seed": seed}
    row["fit_s"] = torchcal("fit", tr, "--robot", robot, "--effects", *START, "--out", work / "fit.json", "--force")
    row["fit"] = val_rms(work / "fit.json", va, work)
    row["discover_s"] = torchcal("discover", tr, "--robot", robot, "--effects", *START, "--out", work / "disc.json",
                                 "--json", work / "hist.json", "--force")
    row["discover"] = val_rms(work / "disc.json", va, work)
    hist = json.loads((work / "hist.json").read_text())
    found = json.loads((work / "disc.json").read_text())["effects"]
    row["effects"] = [e if isinstance(e, str) else e.get("spec", str(e)) for e in found]
    row["learnable"] = (hist.get("unexplained") or {}).get("probe_left_rms_mm")
    torchcal("fit", tr, "--robot", robot, "--effects", *row["effects"], "--residual-model", "kernel",
             "--out", work / "resid.json", "--force")
    row["residual"] = val_rms(work / "resid.json", va, work)
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
    print("\n| series | fit | discover | discover + residual | probe learnable | discover worse than fit | discover wall s |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for s in args.series:
        rs = [r for r in rows if r["series"] == s]

        def ms(key):
            v = [r[key] for r in rs if r[key] is not None]
            if not v:
                return "-"
            return f"{statistics.mean(v):.4f} ± {statistics.stdev(v):.4f}" if len(v) > 1 else f"{v[0]:.4f}"

        worse = sum(r["discover"] > r["fit"] for r in rs)
        walls = sorted(r["discover_s"] for r in rs)
        print(f"| {s.upper()} | {ms('fit')} | {ms('discover')} | {ms('residual')} | {ms('learnable')} | "
              f"{worse} of {len(rs)} | median {statistics.median(walls):.1f} |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
