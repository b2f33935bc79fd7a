"""Tensor FCM (torchcal.partition.fcm) against scikit-fuzzy's cmeans, same data, same start.

    python benchmarks/bench_fcm.py [--n 1000000] [--iters 10] [--eps 0] [--repeats 3] [--threads 2]
                                   [--baseline OLD_FCM.py]

1e6 points in 1-D and 3-D (4 Gaussian blobs), c = 4, m = 2, float64, the same initial
memberships for both, a fixed number of iterations for both (eps = 0 / error = 0 never
stop early); with --eps > 0 both run until their stopping rule ||U(t+1) - U(t)|| < eps
fires (at most --iters iterations) and both iteration counts are printed (torchcal skips
the norm while it cannot fire, and with eps = 0 never computes it: --eps 1e-6 times the
norm too). Both run on the same cores: torch with `torch.set_num_threads(threads)`,
numpy/BLAS limited to the same count, OMP_WAIT_POLICY=PASSIVE (torchcal's policy).
With --baseline, a copy of an earlier torchcal/partition/fcm.py (e.g. `git show
REV:torchcal/partition/fcm.py > /tmp/fcm_old.py`) is timed in the same run, alternately
with the current one, and compared with it bit for bit.
Prints the median (and min) wall time of `repeats` runs (the contenders alternately), the
median CPU seconds of the process (all its threads; on a shared machine the figure to
compare at 1 thread), iterations per second, the speed ratios by wall and by CPU
time, and how far apart the two results are.

Which kernel iterates is printed: the fused one (torchcal/partition/fcm_kernel.c, built
once per machine at first use: the time `_native.kernel()` took in this run is printed, a
few ms when already built) or the eager torch one (TORCHCAL_FCM_KERNEL=torch, or no C
compiler). Then, on one thread, what bounds an iteration: its CPU time per point (the
slope between a 1-iteration and a 10-iteration run at eps = 0, so the start and the final
memberships are left out) beside floors from rates measured in the same run. Fused: the
8 d bytes of x read from memory at the rate of a large sum (the memory-bandwidth bound)
and its one division per point at the rate of an in-cache reciprocal. Eager: the bytes
one iteration moves per point through the L2 cache (eager torch ops, each a pass over the
chunk's (c, n) scratch, `bytes_per_point`) at the rate of an in-cache multiply, its c + 1
divisions per point at the rate of an in-cache reciprocal, x from memory, and the op
dispatches per chunk at the cost of an op on one element.

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


def bytes_per_point(c: int, d: int) -> tuple:
    """What one iteration of torchcal's eager FCM kernel (m = 2, eps = 0, float64) moves per point:
    (bytes through the L2 cache outside the division passes, bytes in the division passes,
    divisions, ops per chunk). The ops on a chunk of n points, each reading and writing
    (c, n) float64 buffers: d = 1: x - v (writes 8c; x itself comes from memory), 1/d^2
    (division pass: 16c); d > 1: (x_1 - v)^2 in one pass, and per further feature x_k - v
    and addcmul (8c + (d-1)(8c + 24c)), 1/d^2 (division pass: 16c); then S = sum over
    the clusters (8c + 8), 1/S (division pass: 16), the check dot(S, 1/S) (16), u = w/S
    (16c + 8), u^2 (16c), and d + 1 matrix-vector products for eq. 27 (8c + 8 each)."""
    dist = 8 * c if d == 1 else 8 * c + (d - 1) * 32 * c
    rest = (8 * c + 8) + 16 + (16 * c + 8) + 16 * c + (d + 1) * (8 * c + 8)
    ops = (2 if d == 1 else 2 * d) + 5 + (d + 1)
    return dist + rest, 16 * c + 16, c + 1, ops


def machine_rates(torch) -> dict:
    """Single-thread rates measured now (CPU time): an in-cache multiply and reciprocal on
    32768 float64 (256 KiB per operand, the kernel's chunk), a sum over 64 MiB (memory), an
    op on one element (dispatch)."""
    import time

    def per_call(fn, reps):
        fn()
        t = time.process_time()
        for _ in range(reps):
            fn()
        return (time.process_time() - t) / reps

    a, b, o = (torch.rand(1 << 15, dtype=torch.float64) + 1.0 for _ in range(3))
    big = torch.rand(1 << 23, dtype=torch.float64)
    one = torch.ones(1, dtype=torch.float64)
    mul = per_call(lambda: torch.mul(a, b, out=o), 2000)
    return {"l2_gbs": 24 * (1 << 15) / mul / 1e9,  # two reads and a write per element
            "div_ns": per_call(lambda: torch.reciprocal(a, out=o), 2000) / (1 << 15) * 1e9,
            "mem_gbs": 8 * (1 << 23) / per_call(big.sum, 20) / 1e9,
            "op_us": per_call(lambda: torch.mul(one, one, out=one), 20000) * 1e6}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000, help="points (default 1e6)")
    ap.add_argument("--iters", type=int, default=10, help="FCM iterations, same for both (default 10); the most with --eps")
    ap.add_argument("--eps", type=float, default=0.0, help="stopping tolerance, same for both (default 0: run --iters)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per method, median reported (default 3)")
    ap.add_argument("--threads", type=int, default=2, help="CPU threads (default 2)")
    ap.add_argument("--baseline", default=None, help="an earlier fcm.py to time beside (same run)")
    args = ap.parse_args(argv)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(args.threads)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # torchcal's policy (torchcal.threads): before torch loads

    import numpy as np
    import skfuzzy
    import torch

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    from torchcal.partition import _native
    from torchcal.partition.fcm import fcm

    t0 = time.perf_counter()
    fused = _native.kernel() is not None
    build_s = time.perf_counter() - t0

    fcm_base = None
    if args.baseline:
        import importlib.util

        spec = importlib.util.spec_from_file_location("fcm_baseline", args.baseline)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        fcm_base = mod.fcm

    torch.set_num_threads(args.threads)
    c, m, K = 4, 2.0, args.iters
    KB = 10  # iterations of the longer run of the bound (eps = 0), whatever --iters and --eps are
    iters = f"{K} iterations (fixed)" if args.eps == 0 else f"until ||dU|| < {args.eps:g} (at most {K} iterations)"
    print(f"FCM benchmark: N={args.n:,} points, c={c}, m={m}, {iters}, float64, "
          f"{args.threads} threads, median of {args.repeats}; torch {torch.__version__}, "
          f"scikit-fuzzy {getattr(skfuzzy, '__version__', '?')}, numpy {np.__version__}")
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())} (machine shared with other jobs)")
    print("kernel: " + (f"fused (fcm_kernel.c; built or loaded in {build_s:.3f} s wall)" if fused else
                        "eager torch (TORCHCAL_FCM_KERNEL=torch, or no C compiler)"))
    print(f"{'d':>2} {'method':<24} {'time s':>8} {'min s':>7} {'cpu s':>7} {'iter/s':>8} {'speed-up':>9} "
          f"{'by cpu':>7}   agreement")
    rng = np.random.default_rng(0)
    bounds = []  # (d, CPU ns per point and iteration)
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

        def run_base():
            res = fcm_base(xt, c, m=m, eps=args.eps, max_iter=K, init_u=u0t)
            return res.centers.numpy(), res.memberships.numpy(), res.n_iter

        if args.threads == 1:
            def run_torch_1():
                return fcm(xt, c, m=m, eps=0.0, max_iter=1, init_u=u0t)

            def run_torch_k():
                return fcm(xt, c, m=m, eps=0.0, max_iter=KB, init_u=u0t)

            cpu = {}
            for name, fn in (("1", run_torch_1), ("K", run_torch_k)):
                fn()
                ts = []
                for _ in range(args.repeats):
                    c0 = time.process_time()
                    fn()
                    ts.append(time.process_time() - c0)
                cpu[name] = statistics.median(ts)
            bounds.append((d, (cpu["K"] - cpu["1"]) / (KB - 1) / args.n * 1e9))
        contenders = [("torchcal.partition.fcm", run_torch), ("skfuzzy.cluster.cmeans", run_skfuzzy)]
        if fcm_base is not None:
            contenders.insert(1, ("baseline", run_base))
        times = {name: ([], []) for name, _ in contenders}
        out = {}
        for name, fn in contenders:
            fn()  # warm-up (allocator, threads)
        for _ in range(args.repeats):  # the contenders alternately, so the load moves them alike
            for name, fn in contenders:
                t0, c0 = time.perf_counter(), time.process_time()
                out[name] = fn()
                times[name][0].append(time.perf_counter() - t0)
                times[name][1].append(time.process_time() - c0)
        times = {name: (statistics.median(ts), min(ts), statistics.median(cs)) for name, (ts, cs) in times.items()}
        (ct, ut, it_t), (cs, us, it_s) = out["torchcal.partition.fcm"], out["skfuzzy.cluster.cmeans"]
        agree = f"max|dV| {np.abs(ct - cs).max():.1e}, max|dU| {np.abs(ut - us).max():.1e}, iterations {it_t} / {it_s}"
        n_it = {"torchcal.partition.fcm": it_t, "skfuzzy.cluster.cmeans": it_s}
        notes = {"torchcal.partition.fcm": agree, "skfuzzy.cluster.cmeans": "(reference)"}
        if fcm_base is not None:
            cb, ub, it_b = out["baseline"]
            n_it["baseline"] = it_b
            same = np.array_equal(cb, ct) and np.array_equal(ub, ut) and it_b == it_t
            notes["baseline"] = (f"{args.baseline}: " + ("centers, memberships, iterations identical to torchcal's"
                                 if same else f"differs from torchcal's: max|dU| {np.abs(ub - ut).max():.1e}"))
        ref, _, ref_cpu = times["skfuzzy.cluster.cmeans"]
        for name, (t, tmin, cpu) in times.items():
            note = notes[name]
            print(f"{d:>2} {name:<24} {t:>8.3f} {tmin:>7.3f} {cpu:>7.3f} {n_it[name] / t:>8.1f} {ref / t:>8.1f}x "
                  f"{ref_cpu / cpu:>6.1f}x   {note}")
    if bounds:
        r = machine_rates(torch)
        chunk = max(1024, (1 << 15) // c)
        print(f"one iteration, 1 thread, CPU time per point (runs of 1 and {KB} iterations, eps 0) against the floor "
              f"of its passes; rates now: in-cache multiply {r['l2_gbs']:.0f} GB/s, reciprocal {r['div_ns']:.2f} ns, "
              f"memory read {r['mem_gbs']:.1f} GB/s, one op {r['op_us']:.2f} us")
        for d, ns in bounds:
            if fused:
                mem, div = 8 * d / r["mem_gbs"], r["div_ns"]
                print(f"{d:>2} {ns:.2f} ns per point (fused); x from memory {8 * d} B {mem:.2f} ns ({ns / mem:.1f}x), "
                      f"1 division {div:.2f} ns ({ns / div:.1f}x)")
                continue
            l2, l2_div, divs, ops = bytes_per_point(c, d)
            parts = {"L2": l2 / r["l2_gbs"], "div": divs * r["div_ns"], "mem": 8 * d / r["mem_gbs"],
                     "ops": ops * r["op_us"] * 1e3 / chunk}
            floor = sum(parts.values())
            print(f"{d:>2} {ns:.2f} ns per point; floor {floor:.2f} ns ({ns / floor:.2f}x): "
                  f"{l2} B through L2 {parts['L2']:.2f} ns + {divs} divisions ({l2_div} B) {parts['div']:.2f} ns + "
                  f"{8 * d} B from memory {parts['mem']:.2f} ns + {ops} ops per {chunk}-point chunk {parts['ops']:.2f} ns")
    print(f"load average after:  {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
