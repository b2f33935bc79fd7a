"""The probe of what is left (`torchcal.diagnosis.probe`): CPU time and the same results
as an earlier revision of `torchcal.kernel_ridge` (the machinery it runs on).

The probe's inputs (variables, residuals, pose ids) are taken from real calls: the probe
that `diagnose` runs on 240 rows of a plain-numpy simulated session (tests/npsim.py, the
KR 1000 Titan, a hidden ``gear_periodic:1``, 0.02 mm noise; ``--seeds`` sessions, one per
seed), probes drawn in numpy with something to learn (``drawn_probe``; ``--drawn`` seeds,
240 rows: the choice nested in the folds; 900 rows: chosen once on a subsample) and,
unless --skip-ur10, the probe that `discover` runs on UR10 series C's training
split (60/40 by pose, seed 0, ``base_frame tool_offset``; 1 664 rows). Each probe then runs
with the baseline's kernel_ridge (``git show BASELINE:torchcal/kernel_ridge.py``, loaded as
a module and swapped into the probe) and with the working tree's, alternating, --repeats
times each (one torch thread); printed: the median process CPU seconds of each and their
ratio, and the equality of the results: the chosen inputs, length scale and ridge of every
`choose` call (equal, or not), and the largest relative difference of the probe's figures
(learnable_rms_mm, p_value, relevance), of every choice's CV error and of the held-out
prediction. The residual stage's `choose` (joint angles only) is compared the same way.

    python benchmarks/bench_probe.py [--baseline ef4d0da] [--repeats 5] [--seeds 3] [--drawn 0 1 2] [--skip-ur10]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
#: the names the probe module imports from torchcal.kernel_ridge.
SWAPPED = ("MAX_ROWS", "MIN_POSES", "block_cv", "choose", "fit_dual", "rbf", "stack_inputs", "subsample",
           "variable_features")


def baseline_module(rev: str):
    """torchcal.kernel_ridge as of git revision `rev`, as a module of its own."""
    src = subprocess.run(["git", "show", f"{rev}:torchcal/kernel_ridge.py"], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / "kernel_ridge_baseline.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("kernel_ridge_baseline", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def captured_probe(call) -> tuple:
    """(args, kwargs) of the probe call that call() makes inside `unexplained` (the last)."""
    U = sys.modules["torchcal.diagnosis.unexplained"]
    seen, real = [], U.probe

    def spy(*a, **k):
        seen.append((a, k))
        return real(*a, **k)

    U.probe = spy
    try:
        call()
    finally:
        U.probe = real
    return seen[-1]


def numpy_session_probe(seed: int) -> tuple:
    """The probe inputs of `diagnose` on 240 poses of the numpy "real" robot (gear_periodic:1)."""
    import torchcal
    from npsim import physics_session
    from torchcal.diagnosis.diagnose import diagnose
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    robot = torchcal.robot("kr1000titan")
    q = random_poses(robot, 240, torch.Generator().manual_seed(seed + 100))
    xyz, payload = physics_session(robot, q.numpy(), seed, ["gear_periodic:1"], noise_mm=0.02)
    m = Measurements(torch.arange(240), q, torch.from_numpy(xyz), torch.from_numpy(payload))
    return captured_probe(lambda: diagnose(robot, m))


def drawn_probe(seed: int, rows: int) -> tuple:
    """Probe inputs drawn in numpy (no robot), with something to learn: six joint angles
    uniform in +-pi, their approach signs, a payload; residual 0.05 sin(2 q2) along x,
    0.03 cos(q5) payload / 10 kg along y, 0.03 mm x approach_q3 along z, and 0.03 mm noise
    per axis; one row per pose."""
    g = np.random.default_rng(seed)
    q = g.uniform(-np.pi, np.pi, size=(rows, 6))
    values = {f"q{j + 1}": q[:, j] for j in range(6)}
    values |= {f"approach_q{j + 1}": np.sign(g.normal(size=rows)) for j in range(6)}
    values["payload_kg"] = g.uniform(0.0, 10.0, rows)
    r = 0.03 * g.normal(size=(rows, 3))
    r[:, 0] += 0.05 * np.sin(2 * q[:, 1])
    r[:, 1] += 0.03 * np.cos(q[:, 4]) * values["payload_kg"] / 10.0
    r[:, 2] += 0.03 * values["approach_q3"]
    return (values, r, np.arange(rows)), {"seed": seed}


def ur10_probe() -> tuple:
    """The probe inputs of `discover` on UR10 series C's training split (as bench_fit.py)."""
    import torchcal
    from torchcal.io.measurement_csv import read_measurements
    from torchcal.io.robot_file import load_robot_file

    ur10 = ROOT / "examples" / "ur10"
    with tempfile.TemporaryDirectory() as tmp:
        train, val = Path(tmp) / "train.csv", Path(tmp) / "val.csv"
        subprocess.run([sys.executable, "-m", "torchcal", "split", str(ur10 / "series_c.csv"), "--robot",
                        str(ur10 / "ur10.json"), "--fraction", "0.6", "--seed", "0", "--out", str(train), str(val),
                        "--force"], check=True, capture_output=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
        robot = load_robot_file(ur10 / "ur10.json")
        m = read_measurements(train, robot=robot)
        return captured_probe(lambda: torchcal.discover(robot, m, ["base_frame", "tool_offset"]))


def run_probe(kr, args, kwargs) -> tuple:
    """(Probe, [choose results], CPU s) of the probe with kernel_ridge module `kr`."""
    import torchcal.diagnosis.probe as PM

    saved = {n: getattr(PM, n) for n in SWAPPED}
    choices = []

    def logged_choose(*a, **k):
        choices.append(kr.choose(*a, **k))
        return choices[-1]

    for n in SWAPPED:
        setattr(PM, n, getattr(kr, n))
    PM.choose = logged_choose
    try:
        c = time.process_time()
        out = PM.probe(*args, **kwargs)
        return out, choices, time.process_time() - c
    finally:
        for n, v in saved.items():
            setattr(PM, n, v)


def rel(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = np.abs(a).max() if a.size else 0.0
    return float(np.abs(a - b).max() / scale) if scale > 0 else float(np.abs(a - b).max() if a.size else 0.0)


def compare(old, new) -> str:
    """One line: are the two probe runs' choices equal, and how far apart are the figures."""
    (po, co, _), (pn, cn, _) = old, new
    same = repr([c[:3] for c in co]) == repr([c[:3] for c in cn]) and \
        repr((po.inputs, po.length_scale, po.ridge)) == repr((pn.inputs, pn.length_scale, pn.ridge))
    figs = lambda p: [p.learnable_rms_mm, p.p_value, *p.relevance.values()]  # noqa: E731
    return (f"choices {'equal' if same else 'DIFFER'} ({len(cn)} choose calls; inputs {pn.inputs}, l {pn.length_scale}, "
            f"ridge {pn.ridge}); rel. difference: figures {rel(figs(po), figs(pn)):.1e}, CV error "
            f"{rel([c[3] for c in co], [c[3] for c in cn]):.1e}, prediction {rel(po.prediction, pn.prediction):.1e}")


def residual_stage_line(old_kr, new_kr, args) -> str:
    """The residual stage's choice (joint angles only, all rows) with both modules."""
    from torchcal.folds import fold_of_pose

    values, r, pose = args[:3]
    out = []
    for kr in (old_kr, new_kr):
        feats = kr.variable_features({k: v for k, v in values.items() if k.startswith("q")})
        fold = fold_of_pose(pose, 0)
        rows = kr.subsample(fold, np.ones(len(r), dtype=bool), pose, 0)
        out.append(kr.choose(feats, list(feats), torch.from_numpy(np.asarray(r, dtype=np.float64)), fold, rows))
    same = repr(out[0][:3]) == repr(out[1][:3])
    return f"residual stage: choice {'equal' if same else 'DIFFER'} {out[1][:3]}, CV error rel. {rel(out[0][3], out[1][3]):.1e}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", default="ef4d0da", help="git revision of the kernel_ridge to compare with")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seeds", type=int, nargs="*", default=[3])
    ap.add_argument("--drawn", type=int, nargs="*", default=[0, 1, 2],
                    help="seeds of the numpy-drawn probes with something to learn (240 and 900 rows each)")
    ap.add_argument("--skip-ur10", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    import torchcal.kernel_ridge as new_kr

    old_kr = baseline_module(args.baseline)
    cases = {f"diagnose, numpy session seed {s} (240 rows)": numpy_session_probe(s) for s in args.seeds}
    for s in args.drawn:
        for rows in (240, 900):
            cases[f"numpy draws with something to learn, seed {s} ({rows} rows)"] = drawn_probe(s, rows)
    if not args.skip_ur10:
        cases["discover, UR10 C training split (1664 rows)"] = ur10_probe()
    print(f"load {tuple(round(x, 2) for x in os.getloadavg())}; one torch thread; baseline {args.baseline}; "
          f"{args.repeats} runs each, alternating; process CPU s, median")
    for name, (a, k) in cases.items():
        cpu = {"old": [], "new": []}
        for _ in range(args.repeats):
            runs = {tag: run_probe(kr, a, k) for tag, kr in (("old", old_kr), ("new", new_kr))}
            for tag in cpu:
                cpu[tag].append(runs[tag][2])
        o, n = statistics.median(cpu["old"]), statistics.median(cpu["new"])
        print(f"{name}: probe CPU baseline {o:.3f} s, now {n:.3f} s ({o / n:.2f}x)")
        print(f"  {compare(runs['old'], runs['new'])}")
        print(f"  {residual_stage_line(old_kr, new_kr, a)}")


if __name__ == "__main__":
    main()
