"""Perturbed forward kinematics: TCP positions per second for (parameter set x pose) pairs.

The sweep of docs/paper.md evaluates every workspace point under many perturbed MD-H tables.
This script times that workload, in one run on one machine, three ways:

- torchcal: `Robot.fk(q, params)` with q (P, n) and params (M, 1, n, 5) -> (M, P, 3) mm,
  twice, alternately: the compiled kernel it runs on a CPU (`torchcal.kinematics.fk_native`,
  fk_kernel.c: one pass per pair, in registers) and the eager torch kernel it runs where
  that is off (TORCHCAL_FK_KERNEL=torch) or not built, `torchcal.kinematics.mdh.positions_into`;
  their ratio from the same run;
- pytorch-kinematics: it cannot batch perturbed link parameters, so one chain per
  parameter set is built before the clock starts (its build time is reported, not
  counted) and `forward_kinematics` is called on all P poses per chain; a subset of the
  M parameter sets is timed and the rate scaled (the work is identical per set);
- numpy: a plain vectorised implementation, the 4x4 MD-H link matrices of the whole
  (chunked) batch multiplied along the chain with `np.matmul`.

and, in the same run, the limits: the compute limit (both kernels: their flops per pair at
the rate of a float matmul on the same threads) and the element-wise limit of the eager
kernel (6 fused element-wise torch ops per joint over 13 multiply-adds per pair: its
element operations per pair at the rate of one in-place fused op, addcmul_ with a broadcast
operand, the kernel's commonest op, on chunk-sized buffers, one per worker), which the
compiled kernel, making no element-wise passes, is not held to. What bounds the compiled
kernel: it is also timed alone on one thread (its inputs made before the clock), writing
all M P pairs to memory and writing an output that stays in cache; alike rates mean it is
bound by its arithmetic, not by memory.

Threads: `--threads N` sets TORCHCAL_THREADS, the workers `Robot.fk` splits its pairs over
(`torchcal.threads.workers`); each runs one torch intra-op thread, the thread policy of
`torchcal.threads.apply` (which sets torch's count to 1 at the first use of torchcal's API:
the header prints both). numpy runs on one thread, pytorch-kinematics on torch's one.

Figures are the median of several repeats (after one warm-up), printed with the targets
(for torchcal also the pairs per CPU second of the process, the figure to compare on a
machine shared with other jobs):
torchcal >= 60 M pairs/s in float64 and >= 100 M/s in float32 on 2 quiet CPU cores, and
>= 50x pytorch-kinematics. `--device cuda` times torchcal (and pytorch-kinematics) on a
GPU instead (target 1e9 pairs/s on an H100); without CUDA it says so and exits 0.

    python benchmarks/bench_fk.py [--robot kr1000titan] [--params 1000] [--poses 1000]
                                  [--repeats 5] [--threads 2] [--device cpu|cuda] [--compare-chunk 65536]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

# the thread count must be fixed before numpy / torch load their thread pools
_THREADS = "2"
for _i, _a in enumerate(sys.argv):
    if _a.startswith("--threads"):
        _THREADS = _a.split("=", 1)[1] if "=" in _a else sys.argv[_i + 1]
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, _THREADS)
os.environ["TORCHCAL_THREADS"] = _THREADS  # Robot.fk's workers (torchcal.threads)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # torchcal's policy (torchcal.threads): before torch loads

import numpy as np  # noqa: E402
import pytorch_kinematics as pk  # noqa: E402
import torch  # noqa: E402
from pytorch_kinematics import transforms as pk_tf  # noqa: E402

import torchcal  # noqa: E402
from _limits import print_limits  # noqa: E402
from torchcal import threads  # noqa: E402
from torchcal.kinematics import fk_native  # noqa: E402
from torchcal.kinematics import mdh as K  # noqa: E402

TARGETS_CPU = {torch.float64: 60e6, torch.float32: 100e6}  # pairs/s on 2 quiet CPU cores
TARGET_GPU = 1e9  # pairs/s on an H100
TARGET_VS_PK = 50.0


# -- the three implementations ----------------------------------------------------------
def _sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _timed_pair(fa, fb, repeats, device):
    """`_timed` of fa and fb, run alternately (after a warm-up of each)."""
    fa(), fb()
    ta, tb = ([], []), ([], [])
    for _ in range(repeats):
        for fn, (ts, cs) in ((fa, ta), (fb, tb)):
            _sync(device)
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            _sync(device)
            ts.append(time.perf_counter() - t0)
            cs.append(time.process_time() - c0)
    return tuple((statistics.median(t), min(t), max(t), statistics.median(c)) for t, c in (ta, tb))


def _eager(fn):
    """fn with the compiled FK kernel turned off while it runs (the eager torch kernel)."""
    def run():
        available = fk_native.available
        fk_native.available = lambda *a: None
        try:
            return fn()
        finally:
            fk_native.available = available
    return run


def _timed(fn, repeats, device):
    """Median, min and max wall time (s) of `fn()` over `repeats` runs after a warm-up,
    and the median CPU time of the process (s, all its threads)."""
    return _timed_pair(fn, lambda: None, repeats, device)[0]


def _md_h_matrix(theta, d, a, alpha, beta):
    """(..., 4, 4) A = Rz(theta) Tz(d) Tx(a) Rx(alpha) Ry(beta) for broadcastable arrays."""
    ct, st, ca, sa, cb, sb = (np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha),
                              np.cos(beta), np.sin(beta))
    shape = np.broadcast_shapes(*(x.shape for x in (ct, sa, cb, d, a)))
    A = np.zeros(shape + (4, 4), dtype=ct.dtype)
    A[..., 0, 0] = ct * cb - st * sa * sb
    A[..., 0, 1] = -st * ca
    A[..., 0, 2] = ct * sb + st * sa * cb
    A[..., 0, 3] = a * ct
    A[..., 1, 0] = st * cb + ct * sa * sb
    A[..., 1, 1] = ct * ca
    A[..., 1, 2] = st * sb - ct * sa * cb
    A[..., 1, 3] = a * st
    A[..., 2, 0] = -ca * sb
    A[..., 2, 1] = sa
    A[..., 2, 2] = ca * cb
    A[..., 2, 3] = d
    A[..., 3, 3] = 1.0
    return A


def numpy_fk(q, table, params, base, tool, chunk=1 << 16):
    """Plain numpy: q (P, n) rad, params (M, n, 5) -> (M, P, 3) mm, chunked over M."""
    M, n, _ = params.shape
    P = q.shape[0]
    out = np.empty((M, P, 3), dtype=q.dtype)
    step = max(1, chunk // P)
    for s in range(0, M, step):
        eff = table + params[s:s + step]  # (m, n, 5)
        T = base
        for i in range(n):
            e = eff[:, None, i, :]  # (m, 1, 5)
            A = _md_h_matrix(q[None, :, i] + e[..., 0], e[..., 1], e[..., 2], e[..., 3], e[..., 4])
            T = np.matmul(T, A)  # (m, P, 4, 4)
        out[s:s + step] = np.matmul(T, tool)[..., :3, 3]
    return out


def pk_chain(robot, params, dtype, device):
    """pytorch-kinematics SerialChain of the robot with deviations params (n, 5), in mm.

    One frame per joint: joint i (revolute about z) sits at S_{i-1} Rz(theta_offset_i),
    S_i = Tz(d) Tx(a) Rx(alpha) Ry(beta), S_0 = base; a fixed joint carries S_n tool.
    Built from float64 matrices (a URDF would pass through float32)."""
    eff = (robot.table + params).to(torch.float64)  # (n, 5)
    zero = torch.zeros(1, dtype=torch.float64)

    def md_h(row):  # (5,) -> (4, 4): A at q = 0
        return K.link_transforms(zero, K.Chain.revolute(row.view(1, 5)))[0]

    prev = robot.base.to(torch.float64)
    origins = []
    for row in eff:
        origins.append(prev @ md_h(row * torch.tensor([1.0, 0, 0, 0, 0], dtype=torch.float64)))  # Rz(off)
        prev = md_h(row * torch.tensor([0.0, 1, 1, 1, 1], dtype=torch.float64))  # S_i
    origins.append(prev @ robot.tool.to(torch.float64))
    root = pk.Frame("base", link=pk.Link("base"), joint=pk.Joint(dtype=dtype))
    parent = root
    for i, T in enumerate(origins):
        kind = "revolute" if i < robot.n else "fixed"
        name = f"link{i + 1}" if i < robot.n else "tcp"
        joint = pk.Joint(f"joint{i + 1}", offset=pk_tf.Transform3d(matrix=T.to(dtype)),
                         joint_type=kind, axis=(0.0, 0.0, 1.0), dtype=dtype)
        child = pk.Frame(name, link=pk.Link(name), joint=joint)
        parent.children = [child]
        parent = child
    return pk.SerialChain(pk.Chain(root, dtype=dtype), "tcp", dtype=dtype).to(dtype=dtype, device=device)


def kernel_alone(robot, q, params, repeats):
    """Pairs per CPU second of the compiled kernel by itself on one thread, q (P, n), params
    (M, n, 5): on all M sets (the output written to memory) and on the first k sets repeated
    M / k times, k such that the output (k P pairs) fills at most 1 MiB and stays in cache.
    Returns the two rates and k."""
    lib = fk_native.available(q.device, q.dtype)
    chain = robot.chain
    lin, base = K.native_frames(chain)
    pose = K.pose_rows(q, chain)
    rates = []
    k = max(1, min(params.shape[0], (1 << 20) // (3 * q.element_size() * q.shape[0])))
    for sets, times in ((params.shape[0], 1), (k, max(1, params.shape[0] // k))):
        link = K.link_rows(chain, params[:sets])
        g = fk_native.grid((sets, q.shape[0]), (1, q.shape[0]), (sets, 1))
        out = torch.empty(sets * q.shape[0], 3, dtype=q.dtype)

        def run():
            for _ in range(times):
                fk_native.fk_positions(lib, pose, link, lin, base, g, out, 1)
        t = _timed(run, repeats, q.device)
        rates.append(sets * times * q.shape[0] / t[3])
    return rates + [k]


# -- the kernel's limits ------------------------------------------------------------------
def kernel_counts(n: int, plain_base: bool) -> tuple[int, int]:
    """(flops, element operations) per pair of `positions_into` for n joints: per joint
    after the last, Rz(q) u (4 mul + 2 add; 2 ops over 2 rows) and R_i z + t_i (9 mul +
    9 add; 4 ops over 3 rows); the world step 6 flops (5 element ops), or 24 (9 + 3 element
    ops) with a base frame."""
    flops = 24 * (n - 1) + (6 if plain_base else 24)
    elems = 16 * (n - 1) + (5 if plain_base else 16)
    return flops, elems


# -- reporting --------------------------------------------------------------------------
def _rate(pairs, t):
    return pairs / t


def _fmt(rate):
    return f"{rate / 1e6:10.3f} M/s"


def _line(label, pairs, timing, target=None, note=""):
    med, lo, hi, _ = timing
    r = _rate(pairs, med)
    spread = f"[{_rate(pairs, hi) / 1e6:.3f} .. {_rate(pairs, lo) / 1e6:.3f}]"
    tgt = ""
    if target is not None:
        tgt = f"target >= {target / 1e6:g} M/s: {'met' if r >= target else 'BELOW TARGET'}"
    print(f"  {label:<34s}{_fmt(r)}  {spread:<22s}{tgt}{note}")
    return r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="kr1000titan", help="preset name (default kr1000titan)")
    ap.add_argument("--params", type=int, default=None,
                    help="parameter sets M (default 1000 on CPU, 10000 on CUDA)")
    ap.add_argument("--poses", type=int, default=None,
                    help="poses P (default 1000 on CPU, 10000 on CUDA)")
    ap.add_argument("--repeats", type=int, default=5, help="timed repeats, median reported (default 5)")
    ap.add_argument("--threads", type=int, default=2, help="torch / numpy CPU threads (default 2)")
    ap.add_argument("--device", default="cpu", choices=("cpu", "cuda"), help="torchcal's device")
    ap.add_argument("--chunk", type=int, default=None,
                    help="torchcal chunk in pairs (default: Robot.fk's, `mdh.chunk_for` the device and dtype; "
                         "2^24 on CUDA)")
    ap.add_argument("--compare-chunk", type=int, default=None,
                    help="also time Robot.fk with this chunk (e.g. 65536, the CPU default before), the two "
                         "alternately in the same run")
    ap.add_argument("--pk-sets", type=int, default=20,
                    help="parameter sets timed with pytorch-kinematics, then scaled (default 20)")
    ap.add_argument("--numpy-sets", type=int, default=None,
                    help="parameter sets timed with numpy, then scaled (default: 1e6 pairs' worth)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    if args.device == "cuda" and not torch.cuda.is_available():
        print("bench_fk: --device cuda asked for, but CUDA is not available here: GPU run skipped.")
        return 0
    device = torch.device(args.device)
    gpu = device.type == "cuda"
    M = args.params or (10000 if gpu else 1000)
    P = args.poses or (10000 if gpu else 1000)
    chunk = args.chunk or ((1 << 24) if gpu else None)  # None: Robot.fk's default per dtype
    pk_sets = min(args.pk_sets, M)
    np_sets = min(args.numpy_sets or max(1, 10 ** 6 // P), M)
    pairs = M * P
    torch.set_num_threads(args.threads)

    robot = torchcal.robot(args.robot)
    n = robot.n
    gen = torch.Generator().manual_seed(args.seed)
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    q64 = lo + (hi - lo) * torch.rand(P, n, generator=gen, dtype=torch.float64)  # (P, n) rad
    scale = torch.tensor([1e-3, 0.5, 0.5, 1e-3, 1e-3], dtype=torch.float64)  # rad, mm, mm, rad, rad
    p64 = torch.randn(M, 1, n, 5, generator=gen, dtype=torch.float64) * scale  # (M, 1, n, 5)

    where = (torch.cuda.get_device_name(device) if gpu
             else f"CPU ({platform.processor() or platform.machine()}, {os.cpu_count()} cores visible)")
    print(f"bench_fk: perturbed forward kinematics, {robot.name} (n = {n}), "
          f"{M} parameter sets x {P} poses = {pairs:,} pairs")
    native = fk_native.available(device, torch.float64) is not None
    print(f"  device: {where}; torch {torch.__version__}, pytorch-kinematics {_version('pytorch_kinematics')}, "
          f"numpy {np.__version__}; load average {os.getloadavg()[0]:.1f} at start")
    print(f"  threads: Robot.fk splits its pairs over {threads.workers()} workers (--threads, TORCHCAL_THREADS), "
          f"each on {torch.get_num_threads()} torch intra-op thread (torchcal's policy, torchcal.threads)")
    print(f"  median of {args.repeats} repeats after one warm-up; [slowest .. fastest] in brackets")
    print(f"  torchcal: Robot.fk(q (P, n), params (M, 1, n, 5)) -> (M, P, 3): "
          + ("the compiled kernel (fk_kernel.c) and the eager torch kernel (positions_into), alternately"
             if native else "the eager torch kernel only: the compiled one is off or not built here")
          + (f"; eager chunk {chunk or 'default (per dtype, below)'}" if not gpu else f"; chunk {chunk}"))
    print(f"  pytorch-kinematics cannot batch perturbed link parameters: one chain per parameter set "
          f"(built before timing,\n    not counted), forward_kinematics on all {P} poses per chain; "
          f"{pk_sets} of the {M} sets timed, rate scaled")
    print(f"  numpy (single-threaded, on the CPU): 4x4 MD-H matrices of the whole batch chained with "
          f"np.matmul, chunks of 65536 pairs{'' if np_sets == M else f'; {np_sets} of the {M} sets timed, rate scaled'}")

    for dtype in (torch.float64, torch.float32):
        dname = str(dtype).replace("torch.", "")
        print(f"\n{dname}:")
        r = robot.to(device=device, dtype=dtype)
        q, params = q64.to(device, dtype), p64.to(device, dtype)

        # torchcal: the compiled kernel and the eager one, alternately
        ck = chunk or K.chunk_for(device, dtype)
        target = TARGET_GPU if gpu else TARGETS_CPU[dtype]
        eager = _eager(lambda: r.fk(q, params, chunk=ck))
        if native and not gpu:
            t_nat, t_tc = _timed_pair(lambda: r.fk(q, params), eager, args.repeats, device)
            rate_nat = _line("torchcal Robot.fk, compiled", pairs, t_nat, target,
                             note=f"; {pairs / t_nat[3] / 1e6:.1f} M pairs per CPU second")
            rate_tc = _line(f"torchcal Robot.fk, eager, chunk {ck}", pairs, t_tc,
                            note=f"{pairs / t_tc[3] / 1e6:.1f} M pairs per CPU second")
            err_nat = (r.fk(q, params) - eager()).abs().max().item()
            print(f"  compiled / eager {rate_nat / rate_tc:17.2f} x by the wall, {t_tc[3] / t_nat[3]:.2f} x per CPU "
                  f"second; largest difference {err_nat:.2e} mm")
            alone, cached, k = kernel_alone(r, q, params[:, 0], args.repeats)
            print(f"  the compiled kernel alone, one thread (factors made and output allocated before the clock): "
                  f"{alone / 1e6:.1f} M pairs per CPU second; on {k} sets repeated (an output that stays in "
                  f"cache): {cached / 1e6:.1f}")
        else:
            t_tc = _timed(eager, args.repeats, device)
            cpu_note = "" if gpu else f"; {pairs / t_tc[3] / 1e6:.1f} M pairs per CPU second"
            rate_tc = rate_nat = _line(f"torchcal Robot.fk, eager, chunk {ck}", pairs, t_tc, target, note=cpu_note)
        out_tc = r.fk(q, params, chunk=ck)  # (M, P, 3)
        if args.compare_chunk:
            e_cmp = _eager(lambda: r.fk(q, params, chunk=args.compare_chunk))
            t_a, t_cmp = _timed_pair(eager, e_cmp, args.repeats, device)
            same = torch.equal(e_cmp(), eager())
            _line(f"torchcal Robot.fk, eager, chunk {args.compare_chunk}", pairs, t_cmp,
                  note=f"(alternately with chunk {ck}; {'the same bits' if same else 'DIFFERENT results'}; "
                       f"{t_cmp[0] / t_a[0]:.2f}x its time; {pairs / t_cmp[3] / 1e6:.1f} M pairs per CPU "
                       f"second: {t_cmp[3] / t_a[3]:.2f}x)")

        # pytorch-kinematics: one chain per parameter set, all poses per call
        t0 = time.perf_counter()
        chains = [pk_chain(robot, p64[m, 0], dtype, device) for m in range(pk_sets)]
        build_ms = (time.perf_counter() - t0) / pk_sets * 1e3

        def run_pk():
            return [c.forward_kinematics(q).get_matrix()[:, :3, 3] for c in chains]

        t_pk = _timed(run_pk, args.repeats, device)
        rate_pk = _line(f"pytorch-kinematics ({pk_sets} sets)", pk_sets * P, t_pk,
                        note=f"chain build {build_ms:.1f} ms per set, not counted")
        err_pk = (torch.stack(run_pk()) - out_tc[:pk_sets]).abs().max().item()

        # numpy, on the CPU
        qn, tn = q64.to(dtype).numpy(), robot.table.to(dtype).numpy()
        pn = p64[:np_sets, 0].to(dtype).numpy()
        bn, tooln = robot.base.to(dtype).numpy(), robot.tool.to(dtype).numpy()
        t_np = _timed(lambda: numpy_fk(qn, tn, pn, bn, tooln), args.repeats, torch.device("cpu"))
        rate_np = _line(f"numpy ({np_sets} sets)" if np_sets < M else "numpy", np_sets * P, t_np)
        err_np = np.abs(numpy_fk(qn, tn, pn, bn, tooln) - out_tc[:np_sets].cpu().numpy()).max()

        if not gpu:
            lim_c, _ = print_limits(rate_tc, *kernel_counts(n, robot.chain.plain_base), dtype, args.threads, ck,
                                    args.repeats, label="eager")
            if native:
                print(f"  compiled: {100 * rate_nat / lim_c:.0f} % of the compute limit; it makes no element-wise "
                      f"passes ({rate_nat / rate_tc:.1f}x the eager kernel)")
        ratio_pk, ratio_np = rate_nat / rate_pk, rate_nat / rate_np
        ok = "met" if ratio_pk >= TARGET_VS_PK else "BELOW TARGET"
        print(f"  torchcal / pytorch-kinematics   {ratio_pk:10.1f} x    target >= {TARGET_VS_PK:g} x: {ok}")
        print(f"  torchcal / numpy                {ratio_np:10.1f} x")
        print(f"  agreement with torchcal: pytorch-kinematics {err_pk:.2e} mm, numpy {err_np:.2e} mm")
    return 0


def _version(module):
    try:
        from importlib.metadata import version
        return version(module.replace("_", "-"))
    except Exception:  # pragma: no cover - only for the printout
        return "?"


if __name__ == "__main__":
    sys.exit(main())
