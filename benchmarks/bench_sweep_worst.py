"""`torchcal sweep --bounds worst` against the default `--bounds sampled` on the kr1000titan
(its Table 2 clearance model), M = 300 states, seed 0.

- bounds: the study's 200 points (benchmarks/study_sweep_samples.py: `sample_workspace`
  seed 0, no keep-out column) swept both ways; printed per point (median, range): the
  sampled bound under the worst bound, 1 - sampled / worst; the worst bound against the
  study's reference (its coordinate ascent from 8 random starts, 720 angles, 30 sweeps);
  the first-order outer bound over the worst bound, outer / worst - 1;
- time: N_TIME points (one block) swept REPEATS times each way, in turn, on one worker
  thread (threads=1); process CPU time per point, medians, and their ratio.

    TORCHCAL_THREADS=1 nice -n 5 python benchmarks/bench_sweep_worst.py
"""

from __future__ import annotations

import statistics
import time

import torch

import torchcal
from study_sweep_samples import N, largest_error  # benchmarks/ is on sys.path when run as a script
from torchcal.reliability.sweep import sweep
from torchcal.reliability.uncertainty import ClearanceModel
from torchcal.robots.workspace import Workspace, sample_workspace

M = 300
N_TIME = 5000
REPEATS = 5


def _pct(x: torch.Tensor) -> str:
    return f"median {100 * float(x.median()):.1f} %, {100 * float(x.min()):.1f} .. {100 * float(x.max()):.1f} %"


def main() -> None:
    robot = torchcal.robot("kr1000titan")
    model = ClearanceModel.defaults(robot)
    q = sample_workspace(robot, N, seed=0, workspace=Workspace(column_radius_mm=0.0))
    s = sweep(robot, q, n_samples=M, seed=0, model=model, linear=False, threads=1)
    w = sweep(robot, q, n_samples=M, seed=0, model=model, linear=False, threads=1, bounds="worst")
    ref = largest_error(robot, model, q)
    print(f"kr1000titan, {N} points, M = {M}: distance bound sampled {float(s.dist_upper.median()):.3f} mm, "
          f"worst {float(w.dist_upper.median()):.3f} mm, outer {float(w.dist_upper_outer.median()):.3f} mm "
          f"(medians over points)")
    print(f"  sampled under worst (1 - sampled / worst): {_pct(1 - s.dist_upper / w.dist_upper)}")
    print(f"  worst vs the study's 8-start ascent (worst / reference - 1): {_pct(w.dist_upper / ref - 1)}")
    print(f"  outer over worst (outer / worst - 1): {_pct(w.dist_upper_outer / w.dist_upper - 1)}")
    print(f"  R_set median sampled {float(s.r_set.median()):.3f}, worst {float(w.r_set.median()):.3f}; "
          f"share at 1: {float((s.r_set >= 1).double().mean()):.2f}, {float((w.r_set >= 1).double().mean()):.2f}")
    qt = sample_workspace(robot, N_TIME, seed=1)
    times = {"sampled": [], "worst": []}
    for _ in range(REPEATS):
        for bounds in times:
            t0 = time.process_time()
            sweep(robot, qt, n_samples=M, seed=0, model=model, threads=1, bounds=bounds)
            times[bounds].append((time.process_time() - t0) / N_TIME * 1e3)
    ts, tw = statistics.median(times["sampled"]), statistics.median(times["worst"])
    print(f"time, {N_TIME} points x {REPEATS} runs each (process CPU, one worker): sampled {ts:.4f} ms/point, "
          f"worst {tw:.4f} ms/point (median), worst / sampled {tw / ts:.1f}")


if __name__ == "__main__":
    main()
