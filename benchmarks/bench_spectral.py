"""Speed of the held-out spectral search of `joint_periodic` orders on real data.

Fits ``base_frame tool_offset`` to the training poses of a UR10 series (60/40 split by
pose, seed 0, as examples/ur10/split.py), then runs `propose_orders` on each joint and
prints per joint the orders found, the grid size, and the wall and CPU seconds of the
search (one run each; the figures depend on the machine's load, printed too).

Usage: python benchmarks/bench_spectral.py [--series c] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch

from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.folds import fold_of_pose
from torchcal.diagnosis.spectral import propose_orders
from torchcal.effects import context_of
from torchcal.io.measurement_csv import read_measurements
from torchcal.io.robot_file import load_robot_file

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--series", default="c")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    robot = load_robot_file(UR10 / "ur10.json")
    m = read_measurements(UR10 / f"series_{args.series}.csv", robot=robot)
    ids = np.unique(m.pose.numpy())
    train_ids = np.random.default_rng(args.seed).permutation(ids)[: int(round(0.6 * len(ids)))]
    m = m.subset(torch.from_numpy(np.isin(m.pose.numpy(), train_ids)))
    ctx = context_of(robot, m)
    model = CalibrationModel.for_measurements(robot, ["base_frame", "tool_offset"], m)
    res = fit(model, ctx, m.xyz, pose=m.pose, rotation=m.rotation)
    r = res.residuals.reshape(-1).numpy()
    A = model.jacobian(res.theta, ctx).reshape(-1, model.n_params)[:, res.report.free].detach().numpy()
    folds = fold_of_pose(m.pose, 0, 5)
    print(f"series {args.series}, {len(m)} training rows, load average {os.getloadavg()[0]:.1f}")
    for j in range(1, robot.n + 1):
        t, c = time.perf_counter(), time.process_time()
        s = propose_orders(robot, model, res.theta, ctx, r, A, folds, j)
        wall, cpu = time.perf_counter() - t, time.process_time() - c
        grid = max(s.limits.k_max - s.limits.k_min + 1, 0)
        print(f"joint {j}: {grid} orders searched, found {list(s.orders)} "
              f"(amplitudes {[round(a) for a in s.amplitudes_arcsec]} arcsec), "
              f"held-out rms {s.cv_rms_mm[0]:.4f} -> {s.cv_rms_mm[-1]:.4f} mm; "
              f"{wall:.2f} s wall, {cpu:.2f} s cpu" if s.cv_rms_mm else f"joint {j}: not searched")


if __name__ == "__main__":
    main()
