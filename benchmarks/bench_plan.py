"""Planned vs random measurement poses: held-out accuracy after calibration.

    PYTHONPATH=. python benchmarks/bench_plan.py [--seeds 10] [--candidates 3000]

Cases (VirtualRobot, hidden geometry drawn per seed, measurement noise 0.03 mm per axis):

- puma560 and kr1000titan, fitted geometric only; the simulated robot also carries joint
  compliance on joints 2 and 3 of 0.05 mm RMS that the fitted model does not contain;
- kr1000titan + joint_compliance:2,3 (0.3 mm RMS), fitted with compliance (payload drawn
  per pose from 0 to rated, as `VirtualRobot.measure` does; the plan evaluates the
  Jacobian at the rated payload).

For N = 20, 40, 80 one D-optimal plan per case (from `--candidates` workspace poses,
seed 0; it is made before any measurement, so it does not see the hidden robot) is
measured on each seed's robot; random plans of N_r = 20, 40, 80, 160, 320 poses come
from the same workspace sampler, new per seed. Held-out RMS: 300 other workspace poses,
measured (with noise), distance residual of the fitted model. Prints the mean over the
seeds and, per planned N, the number of random poses with the same mean held-out RMS
(log-linear interpolation between the random sizes; '>320' if none reaches it).
"""

from __future__ import annotations

import argparse
import math
import time

import torch

import torchcal
from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.effects import make_context
from torchcal.planning import design
from torchcal.robots.workspace import sample_workspace
from torchcal.simulation.virtual_robot import VirtualRobot

CASES = [
    ("puma560", ["joint_compliance:2,3"], [], 0.05),
    ("kr1000titan", ["joint_compliance:2,3"], [], 0.05),
    ("kr1000titan", ["joint_compliance:2,3"], ["joint_compliance:2,3"], 0.3),
]
PLANNED = (20, 40, 80)
RANDOM = (20, 40, 80, 160, 320)


def held_out_rms(vr, model, q_fit, q_test, seed):
    m = vr.measure(q_fit, noise_mm=0.03, seed=seed)
    res = fit(model, make_context(vr.robot, m.q, m.payload_kg, m.temp_c), m.xyz)
    t = vr.measure(q_test, noise_mm=0.03, seed=seed + 7)
    pred = model.predict(res.theta, make_context(vr.robot, t.q, t.payload_kg, t.temp_c))
    return float((t.xyz - pred).norm(dim=-1).pow(2).mean().sqrt())


def matching_random(n_rms, rand_rms):
    """Random plan size with the same held-out RMS (log-log interpolation)."""
    sizes = list(RANDOM)
    for (a, ra), (b, rb) in zip(zip(sizes, rand_rms), zip(sizes[1:], rand_rms[1:])):
        if ra >= n_rms >= rb and ra > rb:
            f = (math.log(ra) - math.log(n_rms)) / (math.log(ra) - math.log(rb))
            return f"{math.exp(math.log(a) + f * (math.log(b) - math.log(a))):.0f}"
    return f"<{sizes[0]}" if n_rms > rand_rms[0] else f">{sizes[-1]}"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--candidates", type=int, default=3000)
    args = ap.parse_args()
    for name, truth_fx, fit_fx, eff_mm in CASES:
        t0 = time.time()
        robot = torchcal.robot(name)
        model = CalibrationModel(robot, fit_fx)
        cand = sample_workspace(robot, args.candidates, seed=0)
        M = cand.shape[0]
        J = design.candidate_jacobian(model, cand, torch.full((M,), robot.payload_kg, dtype=torch.float64))
        _, A = design.scaled_columns(J, model)
        plans = {n: cand[design.select(A, n, "D").index] for n in PLANNED}
        planned = {n: [] for n in PLANNED}
        rand = {n: [] for n in RANDOM}
        for s in range(args.seeds):
            vr = VirtualRobot(robot, truth_fx, seed=100 + s, effect_mm=eff_mm)
            q_test = sample_workspace(robot, 300, seed=10_000 + s)
            for n in PLANNED:
                planned[n].append(held_out_rms(vr, model, plans[n], q_test, 1000 * s + n))
            pool = sample_workspace(robot, max(RANDOM), seed=20_000 + s)
            for n in RANDOM:
                rand[n].append(held_out_rms(vr, model, pool[:n], q_test, 1000 * s + n + 1))
        mean = lambda v: sum(v) / len(v)
        rr = [mean(rand[n]) for n in RANDOM]
        print(f"\n{name}: truth geometry + {truth_fx} ({eff_mm} mm RMS) + noise 0.03 mm; "
              f"fitted [{', '.join(fit_fx) or 'geometric only'}]; {args.seeds} seeds, "
              f"{M} candidates ({time.time() - t0:.0f} s)")
        print("  N     planned held-out RMS mm   random held-out RMS mm   random poses matching")
        for n in PLANNED:
            pm = mean(planned[n])
            print(f"  {n:<5} {pm:<25.4f} {mean(rand[n]):<24.4f} {matching_random(pm, rr)}")
        print("  random only: " + ", ".join(f"N={n}: {r:.4f}" for n, r in zip(RANDOM, rr)))


if __name__ == "__main__":
    main()
