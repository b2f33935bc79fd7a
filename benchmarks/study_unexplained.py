"""Size and power of the "what stays unexplained" report (torchcal.diagnosis.unexplained).

Simulated sessions, seeds 300-319 (20 per case; no test uses them); for each, prints
whether the report is significant, the kernel probe's p-value, its learnable RMS against
the residual RMS and the variables that carry it, the smallest per-variable p-value and
the variables listed. Each case ends with the share of sessions the probe and the whole
report call significant (false alarms on the null cases, power on the others). Null
cases: the simulated robot carries only the fitted model's errors (geometric) plus noise:

- null_norep60 / null_norep240: UR5e, geometric only, 60 / 240 poses, 0.02 mm noise;
- null_rep30: UR5e, 30 poses x 2 repeats;

- null_shared: KR 1000 Titan, geometric deviations only, 60 poses x 4 repeats, 0.02 mm
  noise, a 0.05 mm error per axis shared by each pose's repeats (no physical effect);
- null_small: UR5e, geometric only, 30 poses x 2, 0.02 mm noise;
- smooth60 / smooth240: UR5e, 60 / 240 poses, a hidden smooth error 0.1 mm * sin(2 q2)
  along x (no effect models it); weak60 / weak240: the same at 0.03 mm (about the noise);
- bent: Titan, 240 poses, a TCP error 0.2 mm * sin(2 q3) along z that no effect models;
- coupling30/60/120: UR5e with the user effect examples/joint_coupling.py hidden
  (joint_coupling:3), N poses x 2; `discover` runs without the module, then the report.

    python benchmarks/study_unexplained.py [case ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch

import torchcal
from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.diagnosis.diagnose import discover
from torchcal.diagnosis.unexplained import PROBE_ALPHA, unexplained
from torchcal.effects import make_context
from torchcal.effects.registry import load_module, unregister_effect
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot

SEEDS = range(300, 320)
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
    if case.startswith("null_norep") or case == "null_rep30" or case.startswith(("smooth", "weak")):
        n = int("".join(c for c in case if c.isdigit()))
        m = VirtualRobot(ur, [], seed=seed).measure(random_poses(ur, n, torch.Generator().manual_seed(seed)),
                                                    repeats=2 if case == "null_rep30" else 1, noise_mm=0.02,
                                                    seed=seed + 1)
        if case.startswith(("smooth", "weak")):
            e = torch.zeros(len(m), 3, dtype=torch.float64)
            e[:, 0] = (0.1 if case.startswith("smooth") else 0.03) * torch.sin(2 * m.q[:, 1])
            m = with_error(m, e)
        return ur, m, geometric_residuals(ur, m), ""
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
        unregister_effect("joint_coupling")
        d = discover(ur, m)
        return ur, m, torch.from_numpy(d.unexplained.residuals), f"discover found {d.final_effects}"
    raise SystemExit(f"unknown case {case!r}")


def main(cases):
    for case in cases:
        hits, probe_hits, t0 = 0, 0, time.perf_counter()
        for seed in SEEDS:
            robot, m, r, label = session(case, seed)
            u = unexplained(robot, m, r)
            pmin = min(p for _, p in u.strengths.values())
            hits += u.significant
            probe_hits += u.probe.p_value < PROBE_ALPHA
            listed = ", ".join(f"{v} {s:.2f}" for v, s in u.correlates_with)
            carried = ", ".join(f"{v} {s:.2f}" for v, s in u.carried_by)
            print(f"{case:13s} seed {seed}: significant {u.significant!s:5s} probe p {u.probe.p_value:.1e} "
                  f"probe leaves {u.probe_left_rms_mm:.4f} of {u.rms_mm:.4f} mm [{carried}]; "
                  f"variables min p {pmin:.1e} listed [{listed}] {label}", flush=True)
        print(f"{case}: probe significant in {probe_hits} of {len(SEEDS)} sessions, report significant in "
              f"{hits} of {len(SEEDS)} ({time.perf_counter() - t0:.0f} s)\n", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["null_norep60", "null_norep240", "null_rep30", "null_shared", "null_small", "smooth60",
                          "smooth240", "weak60", "weak240", "bent", "coupling60"])
