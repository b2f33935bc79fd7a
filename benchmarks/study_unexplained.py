"""Size and power of the "what stays unexplained" report (torchcal.diagnosis.unexplained).

Simulated sessions, seeds 50-54 (no test uses them); for each, prints whether the report
is significant, the smallest p-value over the variables, the strongest variable and the
variables listed. Cases:

- null_shared: KR 1000 Titan, geometric deviations only, 60 poses x 4 repeats, 0.02 mm
  noise, a 0.05 mm error per axis shared by each pose's repeats (no physical effect);
- null_small: UR5e, geometric only, 30 poses x 2, 0.02 mm noise;
- bent: Titan, 240 poses, a TCP error 0.2 mm * sin(2 q3) along z that no effect models;
- coupling30/60/120: UR5e with the user effect examples/joint_coupling.py hidden
  (joint_coupling:3), N poses x 2; `discover` runs without the module, then the report.

    python benchmarks/study_unexplained.py [case ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

import torchcal
from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.diagnosis.diagnose import discover
from torchcal.diagnosis.unexplained import unexplained
from torchcal.effects import make_context
from torchcal.effects.registry import load_module, unregister
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot

SEEDS = range(50, 55)
COUPLING = Path(__file__).resolve().parents[1] / "examples" / "joint_coupling.py"


def geometric_residuals(robot, m):
    ctx = make_context(robot, m.q, m.payload_kg, m.temp_c, q_prev=m.q_prev)
    return fit(CalibrationModel(robot, []), ctx, m.xyz).residuals


def with_error(m, dxyz):
    return Measurements(m.pose, m.q, m.xyz + dxyz, m.payload_kg, m.temp_c, q_prev=m.q_prev)


def session(case, seed):
    """(robot, measurements, residuals (N, 3) mm of the model the report looks at, label)."""
    ti, ur = torchcal.robot("kr1000titan"), torchcal.robot("ur5e")
    if case == "null_shared":
        m = VirtualRobot(ti, [], seed=seed).measure(random_poses(ti, 60, seed + 1), repeats=4, noise_mm=0.02, seed=seed + 2)
        shared = 0.05 * torch.randn(60, 3, generator=torch.Generator().manual_seed(seed + 3), dtype=torch.float64)
        m = with_error(m, shared[m.pose])
        return ti, m, geometric_residuals(ti, m), ""
    if case == "null_small":
        m = VirtualRobot(ur, [], seed=seed).measure(random_poses(ur, 30, torch.Generator().manual_seed(seed)), repeats=2, noise_mm=0.02)
        return ur, m, geometric_residuals(ur, m), ""
    if case == "bent":
        m = VirtualRobot(ti, [], seed=seed).measure(random_poses(ti, 240, seed + 1), noise_mm=0.02, seed=seed + 2)
        bend = torch.zeros(len(m), 3, dtype=torch.float64)
        bend[:, 2] = 0.2 * torch.sin(2 * m.q[:, 2])
        m = with_error(m, bend)
        return ti, m, geometric_residuals(ti, m), ""
    if case.startswith("coupling"):
        load_module(str(COUPLING))
        vr = VirtualRobot(ur, ["joint_coupling:3"], seed=seed)
        m = vr.measure(random_poses(ur, int(case[8:]), torch.Generator().manual_seed(seed)), repeats=2, noise_mm=0.02)
        unregister("joint_coupling")
        d = discover(ur, m)
        return ur, m, torch.from_numpy(d.unexplained.residuals), f"discover found {d.final_effects}"
    raise SystemExit(f"unknown case {case!r}")


def main(cases):
    for case in cases:
        hits = 0
        for seed in SEEDS:
            robot, m, r, label = session(case, seed)
            u = unexplained(robot, m, r)
            best = max(u.strengths.items(), key=lambda kv: kv[1][0])
            pmin = min(p for _, p in u.strengths.values())
            hits += u.significant
            listed = ", ".join(f"{v} {s:.2f}" for v, s in u.correlates_with)
            print(f"{case:12s} seed {seed}: significant {u.significant!s:5s} min p {pmin:.1e} "
                  f"strongest {best[0]} R2 {best[1][0]:.2f}; listed [{listed}] {label}", flush=True)
        print(f"{case}: significant in {hits} of {len(SEEDS)} sessions\n", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["null_shared", "null_small", "bent", "coupling30", "coupling60", "coupling120"])
