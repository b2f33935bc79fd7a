"""Time `diagnose` and `discover` at real-data scale (issue 14).

Simulated sessions of the KR 1000 Titan (the project's simulator): 250, 1000 and 4000
poses, one row each, 0.02 mm noise, with two hidden effects (``joint_compliance:2`` and
``gear_periodic:1``) so that `discover` runs three rounds, as on real data. Each case is
timed --repeat times (median printed) with --threads torch/BLAS threads (default 2, the
target machine). Prints the median seconds per call and the ratio to the 250-pose case.

Target: `discover` on 1000 poses <= 60 s on 2 cores.

Run: ``python benchmarks/bench_diagnose.py [--sizes 250 1000 4000] [--repeat N] [--threads T]
[--skip-discover-above P]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

import torchcal
from torchcal.diagnosis.diagnose import diagnose, discover
from torchcal.simulation.virtual_robot import VirtualRobot
from torchcal.robots.poses import random_poses

HIDDEN = ["joint_compliance:2", "gear_periodic:1"]


def session(poses: int, seed: int = 0):
    r = torchcal.robot("kr1000titan")
    vr = VirtualRobot(r, HIDDEN, seed=seed)
    q = random_poses(r, poses, seed + 100)
    return r, vr.measure(q, noise_mm=0.02)


def timed(f, repeat: int) -> tuple[float, object]:
    out, times = None, []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[250, 1000, 4000])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--skip-discover-above", type=int, default=None,
                    help="time only diagnose above this many poses")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    rows, base = [], {}
    print(f"torch threads: {torch.get_num_threads()}; hidden effects: {', '.join(HIDDEN)}")
    print(f"{'poses':>6}{'diagnose s':>12}{'ratio':>8}{'discover s':>12}{'ratio':>8}  found")
    for P in args.sizes:
        r, m = session(P)
        t_d, _ = timed(lambda: diagnose(r, m), args.repeat)
        t_s, res = (float("nan"), None)
        if args.skip_discover_above is None or P <= args.skip_discover_above:
            t_s, res = timed(lambda: discover(r, m), args.repeat)
        base.setdefault("d", t_d)
        base.setdefault("s", t_s)
        found = ", ".join(res.final_effects) if res is not None else "-"
        print(f"{P:>6}{t_d:>12.2f}{t_d / base['d']:>8.2f}{t_s:>12.2f}{t_s / base['s']:>8.2f}  {found}", flush=True)
        rows.append((P, t_d, t_s))


if __name__ == "__main__":
    main()
