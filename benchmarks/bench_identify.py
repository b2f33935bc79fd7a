"""Identification time: torchcal's LM per zone and batched over zones vs scipy's LM.

The problem is the demo's: the KR 1000 Titan with simulated geometric deviations, base
frame offset, joint clearance (Table 2) and noise; 10 zones, 10 repetitions per pose.
Two cases: (1) 10 poses per zone fitted with the geometric MD-H model (25 candidate
parameters, 20 identifiable), analytic Jacobian (eq. 17); (2) 15 poses per zone fitted
with the demo's model (geometric + base_frame + joint_clearance, 43 candidates), Jacobian
by forward-mode autodiff. Every solver gets the same residual (model - interval center),
the same free parameters (from torchcal's identifiability analysis, done once beforehand
and not timed) and the same Jacobian, and starts from nominal.

Timed, median of --repeat runs each:

- scipy per zone: ``scipy.optimize.least_squares(method='lm', jac=analytic)`` (MINPACK)
  on each zone in turn (torch kernels for residual and Jacobian, converted to numpy);
- torchcal per zone: `torchcal.calibration.lm.levenberg_marquardt` on each zone in turn (B = 1);
- torchcal batched: one `levenberg_marquardt` call with the 10 zones stacked (B = 10);
- torchcal identify_zones: identifiability + the one fit (`torchcal.calibration.fit.fit`)
  per zone + interval radii, what ``calibrate`` and the demo run.

Run: ``python benchmarks/bench_identify.py [--repeat N] [--threads T]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import scipy.optimize
import torch

from torchcal.kinematics import mdh as K
from torchcal.calibration.batched import batched_jacobian, batched_predict
from torchcal.calibration.intervals import identify_zones, pose_intervals
from torchcal.calibration.lm import levenberg_marquardt
from torchcal.calibration.model import CalibrationModel
from torchcal.io.robot_file import robot
from torchcal.simulation.virtual_robot import VirtualRobot
from torchcal.robots.workspace import sample_workspace


def problem(effects=(), n_zones=10, per_zone=10, repeats=10, seed=0):
    r = robot("kr1000titan")
    vr = VirtualRobot(r, effects=["base_frame", "joint_clearance"], seed=seed, geometric_scale=1.5,
                      clearance_random=0.2)
    q = sample_workspace(r, n_zones * per_zone, seed=seed + 1)
    # zones: sort by joint 1 so that each zone is a compact sector, as a partition gives
    q = q[torch.argsort(q[:, 0])]
    meas = vr.measure(q, repeats=repeats, noise_mm=0.02, seed=seed + 2)
    data = pose_intervals(meas)
    data = data.subset(torch.argsort(data.pose))
    zones = [data.subset(slice(z * per_zone, (z + 1) * per_zone)) for z in range(n_zones)]
    return r, CalibrationModel(r, list(effects)), zones


def timeit(fn, repeat):
    out, times = None, []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def run_case(title, r, model, zones, repeat):
    Z, m, P = len(zones), len(zones[0]), model.n_params
    fits = identify_zones(model, zones)  # identifiability per zone (not timed below); warms up
    free = torch.stack([f.report.free for f in fits])  # (Z, P)
    ctxs = [z.context(r) for z in zones]
    targets = torch.stack([z.center for z in zones])  # (Z, m, 3)
    x0 = torch.zeros(Z, P, dtype=torch.float64)

    def torch_zone(z):
        c, t = [ctxs[z]], targets[z:z + 1]
        res = lambda x: (batched_predict(model, x, c) - t).reshape(1, -1)  # noqa: E731
        jac = lambda x: batched_jacobian(model, x, c).reshape(1, 3 * m, P)  # noqa: E731
        return levenberg_marquardt(res, x0[z:z + 1], free=free[z], jacobian_fn=jac)

    def torch_per_zone():
        return [torch_zone(z) for z in range(Z)]

    def torch_batched():
        res = lambda x: (batched_predict(model, x, ctxs) - targets).reshape(Z, -1)  # noqa: E731
        jac = lambda x: batched_jacobian(model, x, ctxs).reshape(Z, 3 * m, P)  # noqa: E731
        return levenberg_marquardt(res, x0, free=free, jacobian_fn=jac)

    chain = r.chain

    def scipy_zone(z):
        idx = free[z].nonzero().flatten()
        ctx, t = ctxs[z], targets[z]

        def full(xf):
            x = torch.zeros(P, dtype=torch.float64)
            x[idx] = torch.from_numpy(xf)
            return x

        if model.effects:  # same residual; Jacobian by forward-mode autodiff (CalibrationModel.jacobian)
            def fun(xf):
                return (model.predict(full(xf), ctx) - t).reshape(-1).numpy()

            def jac(xf):
                return model.jacobian(full(xf), ctx).reshape(3 * m, P)[:, idx].numpy()
        else:  # MD-H kernel and its analytic Jacobian (eq. 17)
            def fun(xf):
                return (K.positions(ctx.q, chain, full(xf).reshape(r.n, 5))
                        - t).reshape(-1).numpy()

            def jac(xf):
                return K.param_jacobian(ctx.q, chain, full(xf).reshape(r.n, 5)).reshape(3 * m, P)[:, idx].numpy()
        return scipy.optimize.least_squares(fun, np.zeros(len(idx)), jac=jac, method="lm",
                                            xtol=1e-12, ftol=1e-12, gtol=1e-12)

    def scipy_per_zone():
        return [scipy_zone(z) for z in range(Z)]

    t_sp, sp = timeit(scipy_per_zone, repeat)
    t_tz, _ = timeit(torch_per_zone, repeat)
    t_tb, tb = timeit(torch_batched, repeat)
    t_full, _ = timeit(lambda: identify_zones(model, zones), repeat)

    diff = 0.0
    cost_sp, cost_tb = [], []
    for z in range(Z):
        idx = free[z].nonzero().flatten()
        diff = max(diff, float((tb.x[z, idx] - torch.from_numpy(sp[z].x)).abs().max()))
        cost_sp.append(sp[z].cost)
        cost_tb.append(float(tb.cost[z]))
    print(f"== {title}")
    print(f"   {Z} zones x {m} poses (10 repetitions -> interval centers), model geometric + "
          f"[{', '.join(model.specs()) or 'nothing'}], {int(model.default_free().sum())} candidate parameters, "
          f"{int(free[0].sum())} free in zone 0; torch threads {torch.get_num_threads()}; median of {repeat}")
    print(f"   {'solver':<44}{'total ms':>10}{'per zone ms':>13}{'vs scipy':>10}")
    rows = [("scipy least_squares(method='lm'), per zone", t_sp), ("torchcal LM, per zone (B=1)", t_tz),
            (f"torchcal LM, all zones batched (B={Z})", t_tb),
            ("torchcal identify_zones (+ident., radii)", t_full)]
    for name, t in rows:
        print(f"   {name:<44}{1e3 * t:>10.2f}{1e3 * t / Z:>13.3f}{t_sp / t:>9.2f}x")
    print(f"   iterations: torchcal batched {tb.n_iter.tolist()}, scipy nfev {[s.nfev for s in sp]}")
    print(f"   max |x_torchcal - x_scipy| = {diff:.2e} (rad / mm); cost 0.5|r|^2 summed over zones: "
          f"scipy {sum(cost_sp):.6e}, torchcal {sum(cost_tb):.6e} mm^2")
    print(f"   batched vs per-zone torchcal: {t_tz / t_tb:.2f}x")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    r, model, zones = problem(())
    run_case("geometric model, analytic Jacobian", r, model, zones, args.repeat)
    r, model, zones = problem(("base_frame", "joint_clearance"), per_zone=15)
    run_case("demo model (geometric + base frame + clearance), autodiff Jacobian", r, model, zones, args.repeat)


if __name__ == "__main__":
    main()
