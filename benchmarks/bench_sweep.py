"""Benchmark of the workspace sweep (torchcal.reliability.sweep.sweep) on the CPU.

    .venv/bin/python benchmarks/bench_sweep.py            # headline + scaling table
    .venv/bin/python benchmarks/bench_sweep.py --quick    # small sizes only
    .venv/bin/python benchmarks/bench_sweep.py --distributed [--n 1000000 --m 1000]

Headline: N = 1e5 workspace points x M = 1e3 clearance states of the default KR 1000
Titan model, on 2 CPU threads (torch.set_num_threads(2) and 2 sweep workers), twice: with
the compiled envelope kernel (fk_kernel.c, `torchcal.kinematics.fk_native.error_extremes`)
and with the eager torch kernel (`outer_positions`, TORCHCAL_FK_KERNEL=torch: the code
before it), one after the other, their ratio and the largest difference of the results. Then a
scaling table N = 1e3 .. 1e6 at M = 1e3 (at N = 1e6 M = 1e3 is run if the N = 1e5 time
predicts less than 3 minutes, else M = 1e2, and the table says so). Where a CUDA device
is visible, the headline sweep also runs on it (`sweep(..., device="cuda")`, after a
warm-up) and its time, ns per pair and largest difference to the CPU run are printed
next to the CPU figure.

Each size runs in its own subprocess, so that its memory is its own (tracemalloc does
not see torch's allocations). The peak is the kernel's high-water mark of resident memory
(VmHWM in /proc/self/status), reset just before the sweep by writing 5 to
/proc/self/clear_refs, so that it measures the sweep alone; where that is not possible,
resource's ru_maxrss (the whole process) is used and the table says so. Columns:

- t_sample: Latin hypercube + workspace filter of the N points (not in t_sweep);
- t_sweep: wall time of the sweep (envelopes over N x M, linearised hull, eta, R_set);
- cpu: CPU seconds (user + system) the process spent in it: on a machine shared with
  other work, cpu / t_sweep below 2 shows how much of the 2 cores the sweep got;
- ns/eval: t_sweep per (point, state) pair;
- rss0: resident memory when the sweep starts (Python, torch, the N points);
- sweep: peak during the sweep - rss0: what the sweep adds;
- results: bytes of the returned tensors (O(N), about 250 bytes per point);
- B/pt: sweep / N: the memory the sweep needs per point, whatever M;
- dense: what one N x M x 3 float64 tensor of the errors would need (N M 24 bytes).
Memory per point stays flat: the N x M work runs in fixed buffers (7 x DEFAULT_CHUNK
float64 per thread, sized for a core's L2 cache), only the per-point results grow with N.

--distributed (torchcal.workflows.distributed; needs the extra torchcal[distributed]):
the streamed sweep of N x M (default 1e6 x 1e3, DEFAULT_BLOCK points per block) in this
process on 2 threads vs on a LocalCluster of 2 worker processes (1 thread each), the two
CSVs compared byte for byte; the client's resident memory (peak - start) during the cluster
run; then the overhead per block, from the slope of the run time against the number of
blocks: the same N_o points at M states in blocks of B_small and of B_large,
o = W (T_small - T_large) / (blocks_small - blocks_large) worker-seconds per block (task
round trip, pickling, the block's two files, the per-block set-up of the kernel), in this
process and on the cluster; and from it the smallest block whose overhead is under 1% of
its compute at M states.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time

THREADS = 2


def _status_mb(key: str) -> float | None:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return float(line.split()[1]) / 1024.0  # kB
    except OSError:
        return None
    return None


def _cpu_s() -> float:
    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime


def _reset_peak() -> bool:
    """Reset the resident high-water mark (Linux >= 4.0); False where not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return _status_mb("VmHWM") is not None
    except OSError:
        return False


def _peak_mb(reset_ok: bool) -> float:
    if reset_ok:
        return _status_mb("VmHWM")
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def child(n: int, m: int, threads: int) -> dict:
    import torch

    torch.set_num_threads(threads)
    import torchcal
    from torchcal.reliability.sweep import sweep
    from torchcal.robots.workspace import sample_workspace

    robot = torchcal.robot("kr1000titan")
    sweep(robot, n_points=8, n_samples=16, seed=1, threads=threads)  # warm-up
    t0 = time.perf_counter()
    q = sample_workspace(robot, n, seed=0)
    t_sample = time.perf_counter() - t0
    reset_ok = _reset_peak()
    rss0 = _status_mb("VmRSS") if reset_ok else _peak_mb(False)
    t1, c1 = time.perf_counter(), _cpu_s()
    r = sweep(robot, q, n_samples=m, seed=0, threads=threads)
    t2, c2 = time.perf_counter(), _cpu_s()
    peak = _peak_mb(reset_ok)
    results = sum(v.nbytes for k, v in vars(r).items() if isinstance(v, torch.Tensor) and k != "q")
    return {
        "N": n, "M": m, "threads": threads, "reset_ok": reset_ok,
        "t_sample_s": t_sample, "t_sweep_s": t2 - t1, "cpu_sweep_s": c2 - c1, "ns_per_eval": (t2 - t1) / (n * m) * 1e9,
        "peak_mb": peak, "rss0_mb": rss0, "results_mb": results / 2**20,
        "dense_mb": n * m * 3 * 8 / 2**20,
        "r_set_min": float(r.r_set.min()), "share_r_set_1": float((r.r_set >= 1).double().mean()),
        "dist_upper": r.dist_upper.tolist() if n <= 100_000 else None,
    }


def sweep_counts(n: int) -> tuple[int, int]:
    """(flops, element operations) per (point, state) of the sweep's envelope for n joints:
    `outer_positions` (per joint: cos and sin of q + offset 6 flops, Ry, Rx and the
    translation 14, Rz(q) 6 = 26 flops in 18 element ops), then the error against the
    nominal (3 subtractions), |e|^2 (5 flops, 3 ops) and the running min and max of the 3
    axes and of |e|^2 (8 comparisons, 8 ops)."""
    return 26 * n + 16, 18 * n + 14


def compiled_counts(n: int) -> int:
    """Flops per (point, state) of the compiled envelope kernel for n joints: the recursion
    of `positions_into` (24 per joint after the last, 6 for the last rotation), the error
    (3), |e|^2 (5) and the running extremes (8 comparisons)."""
    return 24 * n - 2


def run_child(n: int, m: int, threads: int = THREADS, eager: bool = False) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads))
    if eager:
        env["TORCHCAL_FK_KERNEL"] = "torch"
    out = subprocess.run([sys.executable, __file__, "--child", str(n), str(m), str(threads)],
                         capture_output=True, text=True, env=env, check=False)
    if out.returncode != 0:
        raise SystemExit(f"child N={n} M={m} failed:\n{out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _row(r: dict, note: str = "") -> str:
    sweep_mb = r["peak_mb"] - r["rss0_mb"]
    if not r["reset_ok"]:
        note = (note + "; " if note else "") + "peak = whole process (ru_maxrss)"
    return (f"{r['N']:>9,d} {r['M']:>6,d} {r['t_sample_s']:>9.2f} {r['t_sweep_s']:>9.2f} "
            f"{r['cpu_sweep_s']:>8.2f} {r['ns_per_eval']:>8.1f} {r['rss0_mb']:>7.0f} {sweep_mb:>7.1f} {r['results_mb']:>8.1f} "
            f"{sweep_mb * 2**20 / r['N']:>6.0f} {r['dense_mb']:>10,.0f}  {note}")


HEADER = (f"{'N':>9} {'M':>6} {'t_sample':>9} {'t_sweep':>9} {'cpu':>8} {'ns/eval':>8} {'rss0':>7} "
          f"{'sweep':>7} {'results':>8} {'B/pt':>6} {'dense':>10}\n"
          f"{'':>9} {'':>6} {'s':>9} {'s':>9} {'s':>8} {'':>8} {'MB':>7} {'MB':>7} {'MB':>8} {'':>6} {'MB':>10}")


def _timed_run(plan, out, client=None):
    from torchcal.workflows.distributed import run_sweep

    w0 = sum(client.run(_cpu_s).values()) if client is not None else 0.0
    t0, c0 = time.perf_counter(), _cpu_s()
    s = run_sweep(plan, out, client=client)
    t, c = time.perf_counter() - t0, _cpu_s() - c0
    w = sum(client.run(_cpu_s).values()) - w0 if client is not None else 0.0
    return t, c, w, s  # wall, this process's cpu (client and LocalCluster scheduler), workers' cpu


def gpu_case(n: int, m: int) -> dict:
    """The sweep of n points x m states on the GPU (after a warm-up) and on the CPU, in this process."""
    import torch

    import torchcal
    from torchcal.reliability.sweep import sweep
    from torchcal.robots.workspace import sample_workspace

    robot = torchcal.robot("kr1000titan")
    q = sample_workspace(robot, n, seed=0)
    sweep(robot, q[:64], n_samples=16, seed=1, device="cuda")  # warm-up (kernels, allocator)
    torch.cuda.synchronize()
    t0 = time.perf_counter()
    r = sweep(robot, q, n_samples=m, seed=0, device="cuda")
    torch.cuda.synchronize()
    t = time.perf_counter() - t0
    cpu = sweep(robot, q, n_samples=m, seed=0)
    diff = float((r.dist_upper.cpu() - cpu.dist_upper).abs().max())
    return {"device": torch.cuda.get_device_name(), "t_sweep_s": t, "ns_per_eval": t / (n * m) * 1e9,
            "r_set_min": float(r.r_set.min()), "max_diff_mm": diff}


def distributed_case(n: int, m: int, workers: int = 2) -> int:
    import filecmp
    import tempfile

    import torch

    torch.set_num_threads(THREADS)
    import torchcal
    from torchcal.workflows.distributed import connect, plan_sweep
    from torchcal.reliability.sweep_blocks import DEFAULT_BLOCK

    robot = torchcal.robot("kr1000titan")
    plan = plan_sweep(robot, n_points=n, n_samples=m, seed=0)
    print(f"\ndistributed: N = {n:,d} points x M = {m:,d} states, blocks of {plan.block:,d} points "
          f"({plan.n_blocks} blocks); in this process on {THREADS} threads vs a LocalCluster of "
          f"{workers} worker processes x 1 thread; load average {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        _timed_run(plan_sweep(robot, n_points=64, n_samples=16), f"{tmp}/warm.csv")  # warm-up
        t_in, cpu_in, _, s_in = _timed_run(plan, f"{tmp}/in.csv")
        print(f"  in-process:  {t_in:8.1f} s (cpu {cpu_in:.1f} s), {t_in / (n * m) * 1e9:.0f} ns per (point, state), "
              f"R_set min {s_in['r_set_min']:.3f}", flush=True)
        t0 = time.perf_counter()
        with connect(workers=workers) as client:
            t_start = time.perf_counter() - t0
            client.run(lambda: __import__("torchcal.workflows.distributed"))  # workers import torch
            reset_ok = _reset_peak()
            rss0 = _status_mb("VmRSS") if reset_ok else _peak_mb(False)
            t_cl, cpu_cl, cpu_w, s_cl = _timed_run(plan, f"{tmp}/cl.csv", client)
            client_mb = _peak_mb(reset_ok) - rss0
            same = filecmp.cmp(f"{tmp}/in.csv", f"{tmp}/cl.csv", shallow=False)
            size_mb = os.path.getsize(f"{tmp}/cl.csv") / 2**20
            print(f"  cluster:     {t_cl:8.1f} s (+{t_start:.1f} s to start it; cpu: workers {cpu_w:.1f} s, "
                  f"client {cpu_cl:.1f} s = {cpu_cl / plan.n_blocks * 1e3:.0f} ms per block), "
                  f"{t_cl / t_in:.2f} x the in-process time; CSV {size_mb:.0f} MB "
                  f"{'identical, byte for byte' if same else 'DIFFERENT'}; client memory +{client_mb:.0f} MB "
                  f"(results {n * 250 / 2**20:.0f} MB if held)", flush=True)

            # overhead per block: the same points in small and large blocks
            n_o, m_o, b_small, b_large = 20_000, m, 200, 5_000
            rows = []
            for where, cl in (("in-process", None), ("cluster", client)):
                w = THREADS if cl is None else workers
                ts, cs = {}, {}
                for b in (b_small, b_large):
                    p = plan_sweep(robot, n_points=n_o, n_samples=m_o, seed=1, block=b)
                    t, c, cw, _ = _timed_run(p, f"{tmp}/o-{where}-{b}.csv", cl)
                    ts[b], cs[b] = t, c + cw
                dk = n_o // b_small - n_o // b_large
                o_wall = w * (ts[b_small] - ts[b_large]) / dk
                o_cpu = (cs[b_small] - cs[b_large]) / dk
                rows.append((where, o_wall, o_cpu))
                print(f"  overhead {where:>10}: N = {n_o:,d} x M = {m_o:,d} in {n_o // b_small} blocks "
                      f"{ts[b_small]:.2f} s (cpu {cs[b_small]:.2f} s), in {n_o // b_large} blocks {ts[b_large]:.2f} s "
                      f"(cpu {cs[b_large]:.2f} s) -> per block {o_wall * 1e3:.1f} ms of wall x {w} workers, "
                      f"{o_cpu * 1e3:.1f} ms cpu", flush=True)
    per_point = cpu_w / n  # cpu-seconds per point at M states, on the cluster's workers
    o_cl = max(rows[1][2], 1e-4)  # cpu: the wall estimate is at the mercy of the load (the window of
    # two tasks per worker hides the round trip's latency, so what a block costs is its cpu)
    b_min = int(math.ceil(100 * o_cl / per_point))
    print(f"  compute per point at M = {m:,d}: {per_point * 1e3:.3f} ms of one core (workers' cpu / N); a block of "
          f"B points costs {per_point * 1e3:.3f} B ms + {o_cl * 1e3:.1f} ms on the cluster")
    print(f"  -> overhead under 1% from B >= {b_min:,d} points; DEFAULT_BLOCK = {DEFAULT_BLOCK:,d}: "
          f"{100 * o_cl / (per_point * DEFAULT_BLOCK):.2f}% overhead, {per_point * DEFAULT_BLOCK:.2f} s per block; "
          f"client: {cpu_cl / plan.n_blocks * 1e3:.0f} ms cpu per block, so one client keeps up with about "
          f"{per_point * DEFAULT_BLOCK / max(cpu_cl / plan.n_blocks, 1e-6):.0f} workers")
    return 0 if same else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="N = 1e3, 1e4 only")
    ap.add_argument("--distributed", action="store_true",
                    help="in-process vs a 2-worker local Dask cluster, and the overhead per block")
    ap.add_argument("--n", type=int, default=1_000_000, help="points of the --distributed case")
    ap.add_argument("--m", type=int, default=1000, help="states of the --distributed case")
    ap.add_argument("--child", nargs=3, type=int, metavar=("N", "M", "THREADS"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(*args.child)))
        return 0

    import platform

    import torch
    print(f"torchcal sweep benchmark: KR 1000 Titan, default clearance model, float64, {THREADS} CPU threads")
    print(f"torch {torch.__version__}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores visible, load average {os.getloadavg()[0]:.1f} at start")
    if args.distributed:
        return distributed_case(args.n, args.m)
    if args.quick:
        print(HEADER)
        for n in (1000, 10000):
            print(_row(run_child(n, 1000)), flush=True)
        return 0

    head = run_child(100_000, 1000)
    before = run_child(100_000, 1000, eager=True)
    diff = max(abs(a - b) for a, b in zip(head.pop("dist_upper"), before.pop("dist_upper")))
    print("\nheadline: N = 1e5 points x M = 1e3 clearance states")
    print(f"  time {head['t_sweep_s']:.2f} s for the sweep (+{head['t_sample_s']:.1f} s sampling), "
          f"{head['ns_per_eval']:.1f} ns per (point, state), {head['cpu_sweep_s']:.2f} s CPU")
    print(f"  the eager kernel (TORCHCAL_FK_KERNEL=torch, the code before), just after: {before['t_sweep_s']:.2f} s, "
          f"{before['ns_per_eval']:.1f} ns per (point, state), {before['cpu_sweep_s']:.2f} s CPU: compiled "
          f"{before['t_sweep_s'] / head['t_sweep_s']:.2f}x faster by the wall, "
          f"{before['cpu_sweep_s'] / head['cpu_sweep_s']:.2f}x by CPU; largest dist_upper difference {diff:.2e} mm; "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"  memory: {head['rss0_mb']:.0f} MB resident before the sweep (Python, torch, q), the sweep "
          f"adds {head['peak_mb'] - head['rss0_mb']:.0f} MB at its peak (results {head['results_mb']:.0f} MB); "
          f"an N x M x 3 float64 error tensor alone would be {head['dense_mb']:,.0f} MB")
    print(f"  R_set min {head['r_set_min']:.3f}, share of points with R_set = 1: {head['share_r_set_1']:.2f}")
    from _limits import print_limits
    from torchcal.reliability.sweep import DEFAULT_CHUNK
    lim_c, _ = print_limits(1e9 / before["ns_per_eval"], *sweep_counts(6), torch.float64, THREADS, DEFAULT_CHUNK,
                            unit="(point, state)", label="eager (whole sweep)")
    lim_n = lim_c * sweep_counts(6)[0] / compiled_counts(6)
    print(f"  compiled: {compiled_counts(6)} flops per (point, state): compute limit {lim_n / 1e6:.0f} M/s; the whole "
          f"sweep {1e3 / head['ns_per_eval']:.1f} M/s = {100 * 1e9 / head['ns_per_eval'] / lim_n:.0f} %")
    if torch.cuda.is_available():  # the same sweep on the GPU, next to the CPU figure
        g = gpu_case(100_000, 1000)
        print(f"  GPU ({g['device']}): {g['t_sweep_s']:.2f} s, {g['ns_per_eval']:.2f} ns per (point, state), "
              f"{head['t_sweep_s'] / g['t_sweep_s']:.1f}x the CPU; R_set min {g['r_set_min']:.3f}, "
              f"largest |dist_upper| difference to the CPU run {g['max_diff_mm']:.2e} mm")
    else:
        print("  GPU: no CUDA device visible, GPU figures skipped")

    print("\nscaling (time linear in N, memory per point flat):")
    print(HEADER)
    rows = [run_child(1000, 1000), run_child(10000, 1000), head]
    for r in rows:
        print(_row(r), flush=True)
    predicted = head["t_sweep_s"] * 10
    m_big = 1000 if predicted < 180 else 100
    if m_big == 100:  # the same N step at M = 1e2, for a like-for-like ratio
        small = run_child(100_000, 100)
        print(_row(small, "M = 1e2, for comparison with the next row"), flush=True)
    big = run_child(1_000_000, m_big)
    note = "" if m_big == 1000 else f"M = 1e2: M = 1e3 predicted {predicted:.0f} s > 3 min"
    print(_row(big, note), flush=True)
    ref = head if m_big == 1000 else small
    print(f"\nN = 1e3 -> 1e4 -> 1e5 at M = 1e3: t_sweep x{rows[1]['t_sweep_s'] / rows[0]['t_sweep_s']:.1f}, "
          f"x{rows[2]['t_sweep_s'] / rows[1]['t_sweep_s']:.1f}; N = 1e5 -> 1e6 at M = {m_big}: "
          f"t_sweep x{big['t_sweep_s'] / ref['t_sweep_s']:.1f}, cpu x{big['cpu_sweep_s'] / ref['cpu_sweep_s']:.1f} "
          f"(linear: x10)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
