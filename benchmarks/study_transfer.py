"""The transfer matrix of the real UR10 series: does a model fitted on one session carry
over to another (docs/real-data.md, "Transfer between sessions")?

For each source series S and target series T (B, C, D of examples/ur10, S != T), the
model fitted on all of S is registered (frame only, `torchcal.register`) on T's first
`--poses` poses (30) and its distance RMS is measured on T's other poses, for:

- nominal: the nominal robot registered on the same poses (no model of S at all);
- fit: ``fit --effects base_frame tool_offset`` on S (geometry);
- discover: ``discover`` on S from the same start;
- named only: ``fit`` on S of the effects discover names (its split-half check's fit
  terms left out): does that label pick the terms that carry?
- discover, check U: ``discover`` on S with the third series U as the transfer check
  (``--transfer U``): a step is kept only when it lowers U's held-out error beyond
  chance (torchcal.diagnosis.transfer); T is never seen; each round's check is printed;
- + residual: ``fit`` of discover's effects with ``--residual-model kernel`` on S.

"!" marks a registration `torchcal register` warns about (rms above 3x the model's
training rms on S). Also printed: each model's training rms on S and the effects found.

Usage: python benchmarks/study_transfer.py [--series b c d] [--poses 30] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import torch

import torchcal
from torchcal.calibration.registration import TransferWarning
from torchcal.diagnosis.transfer import describe_verdict, first_poses
from torchcal.effects import context_of
from torchcal.errors import InputError
from torchcal.io.measurement_csv import read_measurements

ROOT = Path(__file__).resolve().parents[1]
UR10 = ROOT / "examples" / "ur10"
START = ["base_frame", "tool_offset"]


def transfer(model, target, poses: int) -> tuple[float | None, bool]:
    """(held-out distance RMS mm on `target` after `torchcal.register` on its first
    `poses` poses, whether register warned); (None, False) when register refuses."""
    reg_rows = first_poses(target.pose, poses)
    a, b = target.subset(reg_rows), target.subset(~reg_rows)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            res = torchcal.register(model, a)
        except InputError as exc:
            print(f"  register refused: {exc}", flush=True)
            return None, False
    warned = any(issubclass(w.category, TransferWarning) for w in caught)
    with torch.no_grad():
        err = b.xyz - res.model.predict(res.theta, context_of(res.model.robot, b))
        if res.residual_model is not None:  # as `torchcal evaluate` applies it
            err = err - res.residual_model.predict(b.q).to(err)
    return float(err.norm(dim=-1).pow(2).mean().sqrt()), warned


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--series", nargs="+", default=["b", "c", "d"])
    ap.add_argument("--poses", type=int, default=30, help="registration poses of the target (default 30)")
    ap.add_argument("--json", help="write every figure here")
    args = ap.parse_args()
    robot = torchcal.robot(UR10 / "ur10.json")
    data = {s: read_measurements(UR10 / f"series_{s}.csv", robot=robot) for s in args.series}
    models, found, checks = {}, {}, {}
    for s in args.series:  # the models of each source session
        t0 = time.perf_counter()
        models[s, "fit"] = torchcal.fit(robot, data[s], START)
        disc = torchcal.discover(robot, data[s], START)
        models[s, "discover"] = disc.fit
        found[s, "discover"] = disc.final_effects
        # the effects the split-half check names (fit terms dropped), refitted on S
        models[s, "named"] = torchcal.fit(robot, data[s], disc.named)
        found[s, "named"] = disc.named
        models[s, "residual"] = torchcal.fit(robot, data[s], disc.final_effects, residual_model="kernel")
        for u in args.series:
            if u != s:
                chk = torchcal.discover(robot, data[s], START, transfer=data[u], transfer_poses=args.poses)
                models[s, f"check {u}"] = chk.fit
                found[s, f"check {u}"] = chk.final_effects
                checks[s, u] = [h["transfer"] for h in chk.history]
                print(f"  {s.upper()} checked by {u.upper()}, round by round:", flush=True)
                for k, rec in enumerate(checks[s, u]):
                    print("\n".join(f"    {k}: {ln}" for ln in describe_verdict(rec)), flush=True)
        print(f"models of {s.upper()} ({time.perf_counter() - t0:.0f} s): training rms "
              + ", ".join(f"{k[1]} {v.training_rms_mm:.4f} mm" for k, v in models.items() if k[0] == s), flush=True)
        for k, v in found.items():
            if k[0] == s:
                print(f"  {k[1]}: {', '.join(v)}", flush=True)
    rows = []
    print(f"\n| S -> T | nominal | fit | discover | named only | discover, check U | + residual (discover's effects) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for s in args.series:
        for t in args.series:
            if t == s:
                continue
            u = next((x for x in args.series if x not in (s, t)), None)
            row = {"source": s, "target": t, "check": u}
            row["nominal"], _ = transfer(robot, data[t], args.poses)
            cells = []
            for key in ("fit", "discover", "named", f"check {u}", "residual"):
                if (s, key) not in models:
                    cells.append("-")
                    continue
                rms, warned = transfer(models[s, key], data[t], args.poses)
                row[key.split()[0]] = rms
                row[key.split()[0] + "_warned"] = warned
                cells.append("refused" if rms is None else f"{rms:.3f}{' !' if warned else ''}")
            rows.append(row)
            print(f"| {s.upper()} -> {t.upper()} (U = {(u or '-').upper()}) | {row['nominal']:.3f} | "
                  + " | ".join(cells) + " |", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "training_rms_mm": {f"{k[0]} {k[1]}": v.training_rms_mm
                                                                                 for k, v in models.items()},
                                               "effects": {f"{k[0]} {k[1]}": v for k, v in found.items()},
                                               "checks": {f"{k[0]} check {k[1]}": v for k, v in checks.items()}},
                                              indent=1))


if __name__ == "__main__":
    main()
