"""Tensor FCM (torchcal.partition.fcm) against scikit-fuzzy's cmeans, same data, same start.

    python benchmarks/bench_fcm.py [--n 1000000] [--iters 10] [--eps 0] [--repeats 3] [--threads 2]

1e6 points in 1-D and 3-D (4 Gaussian blobs), c = 4, m = 2, float64, the same initial
memberships for both, a fixed number of iterations for both (eps = 0 / error = 0 never
stop early); with --eps > 0 both run until their stopping rule ||U(t+1) - U(t)|| < eps
fires (at most --iters iterations) and both iteration counts are printed (torchcal skips
the norm while it cannot fire, and with eps = 0 never computes it: --eps 1e-6 times the
norm too). Both run on the same cores: torch with `torch.set_num_threads(threads)`,
numpy/BLAS limited to the same count. Prints the median (and min) wall time of `repeats`
runs, the median CPU seconds of the process (all its threads; on a shared machine the
figure to compare at 1 thread), iterations per second, the speed ratios by wall and by CPU
time, and how far apart the two results are.

Timings need cores to themselves: torch's OpenMP threads spin-wait at each op, so on a
machine shared with other busy jobs (the load average is printed) a descheduled thread
stalls every op and the torch times inflate far more than the single-threaded numpy ones.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000, help="points (default 1e6)")
    ap.add_argument("--iters", type=int, default=10, help="FCM iterations, same for both (default 10); the most with --eps")
    ap.add_argument("--eps", type=float, default=0.0, help="stopping tolerance, same for both (default 0: run --iters)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per method, median reported (default 3)")
    ap.add_argument("--threads", type=int, default=2, help="CPU threads (default 2)")
    args = ap.parse_args(argv)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(args.threads)

    import numpy as np
    import skfuzzy
    import torch

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    from torchcal.partition.fcm import fcm

    torch.set_num_threads(args.threads)
    c, m, K = 4, 2.0, args.iters
    iters = f"{K} iterations (fixed)" if args.eps == 0 else f"until ||dU|| < {args.eps:g} (at most {K} iterations)"
    print(f"FCM benchmark: N={args.n:,} points, c={c}, m={m}, {iters}, float64, "
          f"{args.threads} threads, median of {args.repeats}; torch {torch.__version__}, "
          f"scikit-fuzzy {getattr(skfuzzy, '__version__', '?')}, numpy {np.__version__}")
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())} (machine shared with other jobs)")
    print(f"{'d':>2} {'method':<24} {'time s':>8} {'min s':>7} {'cpu s':>7} {'iter/s':>8} {'speed-up':>9} "
          f"{'by cpu':>7}   agreement")
    rng = np.random.default_rng(0)
    for d in (1, 3):
        centers = rng.uniform(-10, 10, size=(c, d))
        x = centers[rng.integers(0, c, args.n)] + rng.standard_normal((args.n, d))  # (N, d)
        u0 = rng.random((c, args.n))
        u0 /= u0.sum(axis=0)  # (c, N)
        xt = torch.from_numpy(x)
        u0t = torch.from_numpy(u0)

        def run_skfuzzy():
            cntr, u, _, _, _, p, _ = skfuzzy.cluster.cmeans(x.T, c, m, error=args.eps, maxiter=K, init=u0)
            return cntr, u, p

        def run_torch():
            res = fcm(xt, c, m=m, eps=args.eps, max_iter=K, init_u=u0t)
            return res.centers.numpy(), res.memberships.numpy(), res.n_iter

        times = {}
        out = {}
        for name, fn in (("torchcal.partition.fcm (torch)", run_torch), ("skfuzzy.cluster.cmeans", run_skfuzzy)):
            fn()  # warm-up (allocator, threads)
            ts, cs = [], []
            for _ in range(args.repeats):
                t0, c0 = time.perf_counter(), time.process_time()
                out[name] = fn()
                ts.append(time.perf_counter() - t0)
                cs.append(time.process_time() - c0)
            times[name] = (statistics.median(ts), min(ts), statistics.median(cs))
        (ct, ut, it_t), (cs, us, it_s) = out["torchcal.partition.fcm (torch)"], out["skfuzzy.cluster.cmeans"]
        agree = f"max|dV| {np.abs(ct - cs).max():.1e}, max|dU| {np.abs(ut - us).max():.1e}, iterations {it_t} / {it_s}"
        n_it = {"torchcal.partition.fcm (torch)": it_t, "skfuzzy.cluster.cmeans": it_s}
        ref, _, ref_cpu = times["skfuzzy.cluster.cmeans"]
        for name, (t, tmin, cpu) in times.items():
            note = agree if name.startswith("torchcal") else "(reference)"
            print(f"{d:>2} {name:<24} {t:>8.3f} {tmin:>7.3f} {cpu:>7.3f} {n_it[name] / t:>8.1f} {ref / t:>8.1f}x "
                  f"{ref_cpu / cpu:>6.1f}x   {note}")
    print(f"load average after:  {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
