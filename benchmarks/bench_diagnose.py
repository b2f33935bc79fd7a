"""Time `diagnose` and `discover` at real-data scale.

Simulated sessions of the KR 1000 Titan (the project's simulator): 250, 1000 and 4000
poses, one row each, 0.02 mm noise, with two hidden effects (``joint_compliance:2`` and
``gear_periodic:1``) so that `discover` runs three rounds, as on real data. Each case is
timed --repeat times (median printed) with --threads torch/BLAS threads (default 2, the
target machine). Prints the median wall and CPU seconds per call and the CPU-time ratio to the smallest case.

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


def timed(f, repeat: int) -> tuple[float, float, object]:
    """Median wall seconds and median process CPU seconds (all threads) of f()."""
    out, wall, cpu = None, [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = f()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu), out


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
    print("wall s: elapsed; cpu s: process CPU time (all threads), less sensitive to a shared machine")
    print(f"{'poses':>6}{'diagnose wall s':>16}{'cpu s':>9}{'ratio':>7}{'discover wall s':>16}{'cpu s':>9}{'ratio':>7}"
          "  found")
    for P in args.sizes:
        r, m = session(P)
        w_d, c_d, _ = timed(lambda: diagnose(r, m), args.repeat)
        w_s, c_s, res = (float("nan"), float("nan"), None)
        if args.skip_discover_above is None or P <= args.skip_discover_above:
            w_s, c_s, res = timed(lambda: discover(r, m), args.repeat)
        base.setdefault("d", c_d)
        base.setdefault("s", c_s)
        found = ", ".join(res.final_effects) if res is not None else "-"
        print(f"{P:>6}{w_d:>16.2f}{c_d:>9.2f}{c_d / base['d']:>7.2f}{w_s:>16.2f}{c_s:>9.2f}{c_s / base['s']:>7.2f}"
              f"  {found}", flush=True)
        rows.append((P, w_d, c_d, w_s, c_s))


if __name__ == "__main__":
    main()
