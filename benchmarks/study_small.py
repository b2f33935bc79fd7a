"""`discover` against `fit` on SMALL real sets: the UR10 series, 30 and 60 poses, 5-fold CV.

The rule judged on held-back robots (issue 28, item 8): `discover` is never worse than
`fit` on any split, fold or set-up. The large UR10 splits (1 600+ training rows) hold
it; this study asks the same of a few dozen poses, as a held-back evaluator with a small
measurement campaign would run it, through the Python API:

- data: examples/ur10/series_b/c/d.csv read with `torchcal.io.measurement_csv`, robot
  examples/ur10/ur10.json, start effects base_frame tool_offset;
- subsets: for each series, size S (30, 60) and subset seed s (0, 1, 2), S distinct pose
  ids drawn without replacement by ``numpy.random.default_rng(s).choice`` from the sorted
  pose ids of the whole series (seeds and sizes fixed before any result was seen); the
  rows keep their approach angles from the whole series (`Measurements.subset`);
- folds: 5 pose-grouped folds of the subset (`torchcal.folds.fold_of_pose(pose, s)`);
  on each fold's training poses ``torchcal.fit(robot, train, START)`` and
  ``torchcal.discover(robot, train, START, residual_model="kernel")`` (discover's own
  defaults: its inner 5 folds, seed 0, alpha, rounds); the held-out poses are predicted
  by ``torchcal.evaluate``: fit, discover's final model without the residual stage
  (the same fitted model with ``residual_model=None``: `discover` adds the stage after
  the loop, so this is exactly what ``discover`` without the option returns) and with
  the stage (when its held-out test let it in).

Printed: one line per fold, then per series and size the mean held-out RMS over the 15
folds (3 subsets x 5) of fit, discover and discover + stage, the folds where each is
worse than fit by RMS, and the worst relative loss (discover / fit - 1). The JSON
(``--json``) holds every fold: the held-out figures, rows outside the calibrated joint
range (`Evaluation.outside_range`), each accepted step of discover (candidate, p-value,
refit CV RMS before and after within the training poses), the residual-stage test.

--nested (a diagnostic): where discover added an effect, the same comparison one level down,
inside the fold's training poses: 5 pose-grouped folds of them (`fold_of_pose(pose, seed)`),
`fit` and `discover` run on four and the fifth predicted, so discover's whole selection
(order search, pre-screen, refit tests) happens on poses the comparison does not use; the
pooled held-out RMS of each.

    TORCHCAL_THREADS=1 nice -n 5 python benchmarks/study_small.py [--series b c d] [--sizes 30 60] [--seeds 0 1 2] [--nested] [--json OUT]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import time
import warnings
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
UR10 = ROOT / "examples" / "ur10"
START = ["base_frame", "tool_offset"]
FOLDS = 5
ARMS = ("fit", "discover", "discover_stage")


def subset_poses(m, size: int, seed: int):
    """The rows of `size` distinct pose ids of `m`, drawn by ``default_rng(seed).choice``
    without replacement from the sorted ids (file order kept, approach angles kept)."""
    ids = np.unique(m.pose.numpy())
    take = np.random.default_rng(seed).choice(ids, size, replace=False)
    return m.subset(torch.from_numpy(np.isin(m.pose.numpy(), take)))


def steps(d) -> list:
    """[{"candidate", "p_value", "cv_before_mm", "cv_after_mm", "gain"}] of each round's
    accepted step of a `Discovery` (refit CV RMS within the training poses)."""
    out = []
    for h in d.history:
        st = h["step"]
        acc = next((r for r in st["refits"] if r.get("accepted")), None)
        if acc is not None:
            before = st["current"]["cv_rms_mm"]
            out.append({"candidate": acc["candidate"], "p_value": acc["p_value"], "cv_before_mm": before,
                        "cv_after_mm": acc["cv_rms_mm"], "gain": 1.0 - acc["cv_rms_mm"] / before,
                        "reason": acc["reason"]})
    return out


def held_out(fm, test) -> dict:
    """rms_mm, max_mm, outside_range of the fitted model on the held-out rows (the range
    warning is recorded, not printed)."""
    import torchcal

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        e = torchcal.evaluate(fm, test)
    return {"rms_mm": e.rms_mm, "max_mm": e.max_mm, "outside_range": e.outside_range}


def nested(robot, train, seed: int) -> dict:
    """The discover-vs-fit comparison one level down, on folds that chose nothing: the
    training poses cut into 5 pose-grouped folds (`fold_of_pose(pose, seed)`), on each
    the other four run through `fit` and `discover` (all of discover's selection inside
    them) and the held-out fold predicted; pooled held-out RMS (mm) of each, and the
    effects each inner discover added."""
    import torchcal
    from torchcal.folds import fold_of_pose

    inner = fold_of_pose(train.pose, seed, FOLDS)
    sq = {"fit": [], "discover": []}
    added = []
    for f in range(FOLDS):
        tr, te = train.subset(torch.from_numpy(inner != f)), train.subset(torch.from_numpy(inner == f))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = torchcal.discover(robot, tr, START)
            for a, fm in (("fit", torchcal.fit(robot, tr, START)), ("discover", d.fit)):
                sq[a].append(torchcal.evaluate(fm, te).residuals_mm.pow(2).sum(-1))
        added.append([e for e in d.final_effects if e not in START])
    rms = {a: float(torch.cat(v).mean().sqrt()) for a, v in sq.items()}
    return {"fit_rms_mm": rms["fit"], "discover_rms_mm": rms["discover"], "added": added}


def one_fold(robot, ms, fold: np.ndarray, k: int, seed: int = 0, with_nested: bool = False) -> dict:
    import torchcal

    train, test = ms.subset(torch.from_numpy(fold != k)), ms.subset(torch.from_numpy(fold == k))
    t0 = time.process_time()
    f = torchcal.fit(robot, train, START)
    fit_cpu = time.process_time() - t0
    t0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = torchcal.discover(robot, train, START, residual_model="kernel")
    disc_cpu = time.process_time() - t0
    plain = dataclasses.replace(d.fit, residual_model=None)
    added = list(d.final_effects) != list(START)
    return {"nested": nested(robot, train, seed) if with_nested and added else None,"fold": k, "train_poses": int(np.unique(train.pose.numpy()).size),
            "test_poses": int(np.unique(test.pose.numpy()).size),
            "fit": held_out(f, test), "discover": held_out(plain, test),
            "discover_stage": held_out(d.fit, test),
            "fit_train_rms_mm": f.rms_mm, "discover_train_rms_mm": d.fit.rms_mm,
            "effects": list(d.final_effects), "named": list(d.named), "steps": steps(d),
            "stage_test": d.fit.residual_test, "fit_cpu_s": fit_cpu, "discover_cpu_s": disc_cpu}


def summary(rows: list) -> dict:
    """Mean held-out RMS per arm, and per discover arm the folds worse than fit and the
    worst relative loss (rms / fit rms - 1; negative: every fold better)."""
    out = {"folds": len(rows)}
    for a in ARMS:
        out[f"{a}_mean_mm"] = statistics.fmean(r[a]["rms_mm"] for r in rows)
    for a in ARMS[1:]:
        rel = [r[a]["rms_mm"] / r["fit"]["rms_mm"] - 1.0 for r in rows]
        out[f"{a}_worse"] = sum(x > 0 for x in rel)
        out[f"{a}_worst_rel"] = max(rel)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--series", nargs="+", default=["b", "c", "d"])
    ap.add_argument("--sizes", nargs="+", type=int, default=[30, 60])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--nested", action="store_true",
                    help="where discover added an effect, also compare discover with fit by a 5-fold CV "
                         "inside the training poses with discover run inside each fold (a diagnostic)")
    args = ap.parse_args(argv)

    from torchcal.folds import fold_of_pose
    from torchcal.io.measurement_csv import read_measurements
    from torchcal.io.robot_file import robot as make_robot

    robot = make_robot(UR10 / "ur10.json")
    results, table = [], []
    for s in args.series:
        m = read_measurements(UR10 / f"series_{s}.csv", robot=robot)
        for size in args.sizes:
            rows = []
            for seed in args.seeds:
                ms = subset_poses(m, size, seed)
                fold = fold_of_pose(ms.pose, seed, FOLDS)
                for k in range(FOLDS):
                    r = {"series": s, "size": size, "seed": seed, **one_fold(robot, ms, fold, k, seed, args.nested)}
                    rows.append(r)
                    acc = ", ".join(f"{x['candidate']} (p {x['p_value']:.3g}, gain {100 * x['gain']:.1f} %)"
                                    for x in r["steps"]) or "-"
                    print(f"{s} {size:3d} seed {seed} fold {k}: {r['train_poses']}/{r['test_poses']} poses; "
                          f"fit {r['fit']['rms_mm']:.4f} discover {r['discover']['rms_mm']:.4f} "
                          f"+stage {r['discover_stage']['rms_mm']:.4f} mm ({100 * (r['discover']['rms_mm'] / r['fit']['rms_mm'] - 1):+.1f} %); "
                          f"outside range {r['fit']['outside_range']}; accepted {acc}; "
                          f"stage {'in' if r['stage_test'] and r['stage_test']['applied'] else 'out'}; "
                          f"discover {r['discover_cpu_s']:.1f} s CPU", flush=True)
                    if r["nested"]:
                        n = r["nested"]
                        print(f"    nested within the training poses: fit {n['fit_rms_mm']:.4f} discover "
                              f"{n['discover_rms_mm']:.4f} mm; inner discovers added {n['added']}", flush=True)
            results += rows
            table.append({"series": s, "size": size, **summary(rows)})
    print("\nseries size folds | mean held-out RMS mm: fit  discover  +stage | discover worse (worst) | +stage worse (worst)")
    for t in table:
        print(f"  {t['series']}   {t['size']:3d}   {t['folds']:3d} | {t['fit_mean_mm']:.4f}  {t['discover_mean_mm']:.4f}  "
              f"{t['discover_stage_mean_mm']:.4f} | {t['discover_worse']:2d} ({100 * t['discover_worst_rel']:+.1f} %) | "
              f"{t['discover_stage_worse']:2d} ({100 * t['discover_stage_worst_rel']:+.1f} %)")
    if args.json is not None:
        args.json.write_text(json.dumps({"table": table, "folds": results}, indent=1, default=float))
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
