"""The workspace sweep in blocks: in this process or on a Dask cluster, streamed, resumable.

    plan = plan_sweep(robot, n_points=10**6, n_samples=1000, allowed_mm=2.5, seed=0)
    with connect(workers=2) as client:            # or connect(scheduler="tcp://host:8786")
        summary = run_sweep(plan, "sweep.csv", client=client)

A block of points (`sweep_block`; its points drawn (`torchcal.reliability.sweep_blocks`) from the
block's own seed, the same clearance states for every block) is one task (it carries the
plan: robot and states); each worker runs
the sweep's batched kernel on it and sends back the block's CSV rows and summary
statistics, which this process writes block by block (`torchcal.io.sweep_blocks`), so its
memory does not grow with N. The output file is the same, byte for byte, as
`write_sweep(sweep(robot, n_points=..., seed=..., block=...))` in one process, whatever the
number of workers. A run that stops (killed, a lost connection) leaves its finished blocks;
the same run started again computes only the missing ones. A worker that dies mid-block
is replaced by Dask and its task run again; a block reaches the output once.

Dask is imported only here, and only when a cluster is asked for (`connect`): it is the
optional extra ``pip install 'torchcal[distributed]'``. docs/scale.md: running on a cluster.
"""

from __future__ import annotations

import hashlib
import logging
import sys
import uuid
from contextlib import contextmanager
from dataclasses import asdict, dataclass, fields

import numpy as np
import torch
from tqdm import tqdm

from torchcal import threads as policy
from torchcal.errors import InputError
from torchcal.io.files import check_output
from torchcal.io.robot_file import robot_fingerprint
from torchcal.io.sweep_blocks import BlockFolder
from torchcal.io.sweep_csv import sweep_csv_rows, sweep_head
from torchcal.reliability.interval import Interval
from torchcal.robots.workspace import Workspace
from torchcal.reliability.sweep import (DEFAULT_CHUNK, DEFAULT_CHUNK_GPU, SweepResult, _check_allowed,
                                        _check_count, _serial_ops, _sweep_points, sweep_states)
from torchcal.reliability.sweep_blocks import DEFAULT_BLOCK, block_points, block_range

EXTRA_HINT = "pip install 'torchcal[distributed]'"
R_BINS = 10_000  # R_set histogram over [0, 1]: the summary's median to 1e-4
RATIO_BINS = 20_000  # sampled / linearised half-width over [0, 2]: its median to 1e-4


def sweep_block(robot, index: int, *, n_points: int, deviations: torch.Tensor, dev_box: Interval | None = None,
                allowed_mm: float = 2.5, seed: int = 0, block: int = DEFAULT_BLOCK,
                workspace: Workspace | None = None, include_nominal: bool = True,
                allowed_axis_mm: float | None = None, chunk: int | None = None, threads: int = 1,
                dtype=torch.float64, device=None) -> SweepResult:
    """Block `index` of `sweep(robot, n_points=n_points, seed=seed, block=block, ...)` on
    `device` (default the CPU; chunk default per device, as in `sweep`).

    deviations, dev_box: `sweep_states(robot, n_samples=M, seed=seed, model=...)` (the
    same for every block); the linearised hull is computed when dev_box is given. The
    result's `point` holds the global point ids; it equals the block's rows of the
    in-process sweep bit for bit (same points, same kernel on the same block), whatever
    `threads` and `chunk` (on the same device).
    """
    _check_allowed(allowed_mm, allowed_axis_mm)
    device = torch.device(device or "cpu")
    gpu = device.type != "cpu"
    rb = robot.to(device, dtype)
    a0, a1 = block_range(index, n_points=n_points, block=block)
    with _serial_ops(not gpu):
        q = rb.check_q(block_points(robot, index, n_points=n_points, block=block, seed=seed, workspace=workspace))
        q = q.to(device=device, dtype=dtype)
        box = None if dev_box is None else dev_box.to(device, dtype)
        r = _sweep_points(rb, q, deviations.to(device=device, dtype=dtype), box, include_nominal=include_nominal,
                          linear=dev_box is not None, allowed_mm=allowed_mm, allowed_axis_mm=allowed_axis_mm,
                          chunk=chunk or (DEFAULT_CHUNK_GPU if gpu else DEFAULT_CHUNK), threads=1 if gpu else threads,
                          bar=None)
    return SweepResult(**{**{f.name: getattr(r, f.name) for f in fields(r)},
                          "point": torch.arange(a0, a1, device=device)})


@dataclass(frozen=True, eq=False)
class SweepPlan:
    """Everything a block needs (sent with every task). Build it with `plan_sweep`.

    Attributes:
        robot: the `torchcal.Robot` (CPU, float64).
        n_points, n_samples: N points, M clearance states.
        allowed_mm: allowed distance error D (mm).
        seed: seed of the points (per block, `block_seed`) and of the states.
        block: points per block.
        deviations: (M, n, 5) the clearance states as MD-H deviations (rad, mm).
        dev_box: Interval (n, 5) of the deviations (the linearised hull's box).
        workspace: the Workspace filter (None: default).
    """

    robot: object
    n_points: int
    n_samples: int
    allowed_mm: float
    seed: int
    block: int
    deviations: torch.Tensor
    dev_box: Interval
    workspace: Workspace | None = None

    @property
    def n_blocks(self) -> int:
        return -(-self.n_points // self.block)

    def block_points(self, index: int) -> int:
        a0, a1 = block_range(index, n_points=self.n_points, block=self.block)
        return a1 - a0

    def manifest(self) -> dict:
        """What the sweep computes: a rerun takes up a partial output only if this matches."""
        states = _digest([self.deviations, self.dev_box.lower, self.dev_box.upper])
        return {"format": "torchcal sweep blocks 1", "robot": self.robot.name,
                "robot_parameters_sha256": robot_fingerprint(self.robot),
                "clearance_states_sha256": states, "points": self.n_points, "samples": self.n_samples,
                "allowed_mm": self.allowed_mm, "seed": self.seed, "block": self.block,
                "workspace": asdict((self.workspace or Workspace()).for_robot(self.robot))}

    def compute(self, index: int, threads: int = 1, device=None) -> tuple[str, dict]:
        """Block `index` (on `device`, default the CPU): its CSV rows (torchcal.io.sweep_csv)
        and statistics (`block_stats`)."""
        r = sweep_block(self.robot, index, n_points=self.n_points, deviations=self.deviations,
                        dev_box=self.dev_box, allowed_mm=self.allowed_mm, seed=self.seed, block=self.block,
                        workspace=self.workspace, threads=threads, device=device)
        return sweep_csv_rows(r), block_stats(r)


def _digest(tensors) -> str:
    h = hashlib.sha256()
    for t in tensors:
        h.update(t.detach().to("cpu", torch.float64).contiguous().numpy().tobytes())
    return h.hexdigest()


def plan_sweep(robot, *, n_points: int, n_samples: int = 300, allowed_mm: float = 2.5, seed: int = 0,
               model=None, block: int = DEFAULT_BLOCK, workspace: Workspace | None = None) -> SweepPlan:
    """The plan of `sweep(robot, n_points=..., n_samples=..., seed=..., model=..., block=...)`
    computed block by block (the clearance states are drawn here, once)."""
    _check_count(n_points, "number of workspace points")
    _check_count(block, "points per block")
    _check_allowed(allowed_mm, None)
    deviations, dev_box = sweep_states(robot, n_samples=n_samples, seed=seed, model=model)
    return SweepPlan(robot=robot.to("cpu", torch.float64), n_points=int(n_points), n_samples=int(n_samples),
                     allowed_mm=float(allowed_mm), seed=int(seed), block=int(block), deviations=deviations,
                     dev_box=dev_box, workspace=workspace)


def block_stats(r: SweepResult) -> dict:
    """Summary statistics of a block: counts, exact
    minima and maxima, histograms of R_set and of the linear ratio (for the medians): merge
    them with `merge_stats`, read them with `summary_of`."""
    rs = r.r_set.detach().double().cpu().numpy()
    out = {"points": np.int64(len(rs)), "r_set_min": rs.min(), "r_set_max": rs.max(),
           "r_set_1": np.int64((rs >= 1.0).sum()), "r_set_hist": np.histogram(rs[rs < 1.0], R_BINS, (0.0, 1.0))[0],
           "dist_upper_min": r.dist_upper.min().item(), "dist_upper_max": r.dist_upper.max().item()}
    ratio = r.linear_ratio()
    if ratio is not None:
        ratio = ratio.detach().double().cpu().numpy().ravel()
        out["ratio_max"] = ratio.max()
        out["ratio_hist"] = np.histogram(np.clip(ratio, 0.0, 2.0), RATIO_BINS, (0.0, 2.0))[0]
    return {k: np.asarray(v) for k, v in out.items()}


def _hist_median(hist: np.ndarray, lo: float, hi: float, top: int = 0, top_value: float = 1.0) -> float:
    """Median of the values counted in `hist` (bins over [lo, hi]) and `top` values equal
    to top_value (above every bin): bin centers, the mean of the two middle ones for an
    even count, as numpy's median."""
    cum = np.cumsum(hist)
    n = int(cum[-1]) + top
    width = (hi - lo) / len(hist)

    def at(rank):  # 0-based rank
        if rank >= cum[-1]:
            return top_value
        return lo + (np.searchsorted(cum, rank, side="right") + 0.5) * width

    return 0.5 * (at((n - 1) // 2) + at(n // 2))


def merge_stats(acc: dict | None, stats: dict) -> dict:
    """The `block_stats` of two sets of blocks merged into one (acc None: a copy of stats)."""
    if acc is None:
        return {k: np.array(v) for k, v in stats.items()}
    out = dict(acc)
    for k in ("points", "r_set_1", "r_set_hist", "ratio_hist"):
        if k in out:
            out[k] = out[k] + stats[k]
    for k in ("r_set_min", "dist_upper_min"):
        out[k] = np.minimum(out[k], stats[k])
    for k in ("r_set_max", "dist_upper_max", "ratio_max"):
        if k in out:
            out[k] = np.maximum(out[k], stats[k])
    return out


def summary_of(stats: dict) -> dict:
    """`SweepResult.summary()` from the merged `block_stats` of all blocks (medians to 1e-4)."""
    n, r1 = int(stats["points"]), int(stats["r_set_1"])
    out = {"points": n, "r_set_min": float(stats["r_set_min"]),
           "r_set_median": _hist_median(stats["r_set_hist"], 0.0, 1.0, r1),
           "r_set_max": float(stats["r_set_max"]), "share_r_set_1": r1 / n,
           "dist_upper_min_mm": float(stats["dist_upper_min"]), "dist_upper_max_mm": float(stats["dist_upper_max"])}
    if "ratio_hist" in stats:
        out["linear_ratio_median"] = _hist_median(stats["ratio_hist"], 0.0, 2.0)
        out["linear_ratio_max"] = float(stats["ratio_max"])
    return out


def _dask():
    try:
        from dask import distributed
    except ImportError:
        raise InputError(f"a sweep on a cluster (a scheduler or workers) needs Dask: {EXTRA_HINT}") from None
    return distributed


@contextmanager
def connect(*, scheduler: str | None = None, workers: int | None = None, timeout_s: float = 30.0):
    """A dask.distributed Client of the scheduler at `scheduler` (an address such as
    tcp://host:8786), or of a LocalCluster of `workers` processes of one thread each, or
    None (neither given: the sweep runs in this process). Closed when the block ends."""
    if scheduler is None and workers is None:
        yield None
        return
    if scheduler is not None and workers is not None:
        raise InputError("give either a scheduler address or a number of local workers, not both")
    distributed = _dask()
    cluster = None
    try:
        if scheduler is not None:
            client = distributed.Client(scheduler, timeout=timeout_s)
        else:
            _check_count(workers, "number of workers")
            # silence_logs: the cluster's own warnings (a worker slow to exit at shutdown on a
            # busy machine, then stopped) are not the user's business; errors still show
            # preload: each worker process imports torch as the command line does (torchcal.threads.dask_setup)
            cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                               dashboard_address=":0", silence_logs=logging.ERROR,
                                               preload=["torchcal.threads"])
            client = distributed.Client(cluster, timeout=timeout_s)
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close(timeout=timeout_s)
        where = f"scheduler {scheduler}" if scheduler is not None else f"local cluster of {workers} workers"
        raise InputError(f"cannot connect to the Dask {where}: {exc}") from None
    try:
        yield client
    finally:
        client.close(timeout=timeout_s)
        if cluster is not None:
            cluster.close(timeout=timeout_s)


def _run_block(plan: SweepPlan, index: int):
    """One task on a worker: block `index` on one thread."""
    policy.apply()  # a fresh worker process: torch and BLAS on one thread
    return plan.compute(index, threads=1)


def run_sweep(plan: SweepPlan, out, *, client=None, threads: int | None = None, processes: int | None = None,
              device=None, force: bool = False, progress: bool = False, on_block=None, log=None) -> dict:
    """Compute the missing blocks of `plan` and write the sweep CSV `out` block by block.

    client: a dask.distributed Client (`connect`): blocks are its tasks, at most two per
        worker thread at a time, written here as they come back; None: computed on this
        machine, without Dask.
    threads: in this process, the worker threads within a block (default
        `torchcal.threads.workers()`).
    processes: without a client, the number of child processes of this machine that
        compute whole blocks, one thread each (`run_in_processes`); None: in this process.
    device: without a client or processes, the device of this process that computes the
        blocks (default the CPU; a GPU's vectorised sin / cos may differ from the CPU's in
        the last bit, docs/scale.md).
    force: discard a partial output of a sweep with other arguments (same arguments:
        its blocks are kept and the run goes on from them).
    on_block: called with the index of each block once it is written.
    log: called with one line when finished blocks are taken up.

    Returns the summary (`summary_of`: the keys of `SweepResult.summary()`). InputError when
    `out` exists without force or `out`.blocks holds another sweep.
    """
    out = check_output(out, force)
    folder = BlockFolder(out)
    done = folder.open(plan.manifest(), force=force)
    missing = [b for b in range(plan.n_blocks) if b not in done]
    if done and log is not None:
        log(f"sweep: resuming {out}: {len(done)} of {plan.n_blocks} blocks already done in {folder.path}, "
            f"computing the {len(missing)} missing")
    with tqdm(total=plan.n_points, initial=sum(plan.block_points(b) for b in done), unit="pt", desc="sweep",
              file=sys.stderr, disable=None if progress else True, dynamic_ncols=True) as bar:
        acc = None
        for b in sorted(done):  # the statistics of the blocks done before, merged as they come
            acc = merge_stats(acc, folder.stats(b))

        def write(index, rows, stats):
            nonlocal acc
            folder.write(index, rows, stats)
            acc = merge_stats(acc, stats)
            bar.update(plan.block_points(index))
            if on_block is not None:
                on_block(index)

        if client is None and processes is not None and min(processes, len(missing)) > 1:
            run_in_processes(plan, missing, write, processes)
        elif client is None:
            for b in missing:
                write(b, *plan.compute(b, threads=threads or policy.workers(), device=device))
        else:
            _run_on(client, plan, missing, write)
    summary = summary_of(acc)
    folder.assemble(sweep_head(plan.robot.n, plan.robot), plan.n_blocks)
    from torchcal.reliability.sweep import warn_allowed
    warn_allowed(summary, plan.allowed_mm, stacklevel=2)  # an allowed error in metres or micrometres
    return summary


def run_in_processes(plan: SweepPlan, missing: list[int], write, processes: int) -> None:
    """The blocks `missing` on `processes` child processes of this machine (no cluster,
    no Dask): each computes whole blocks on one thread, two blocks per process in flight;
    `write(block, rows, stats)` here as each comes back. Fresh interpreters ("spawn"),
    so no OpenMP state of this process is forked."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    _check_count(processes, "number of worker processes")
    todo = iter(missing)
    running = {}  # future -> block
    # each process imports torch as the command line does (the import's objects frozen)
    with ProcessPoolExecutor(min(processes, len(missing)), mp_context=multiprocessing.get_context("spawn"),
                             initializer=policy.apply_importing) as pool:
        def top_up():
            while len(running) < 2 * processes:
                b = next(todo, None)
                if b is None:
                    return
                running[pool.submit(_run_block, plan, b)] = b

        top_up()
        while running:
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for f in finished:
                write(running.pop(f), *f.result())
            top_up()


def _run_on(client, plan: SweepPlan, missing: list[int], write) -> None:
    """The blocks `missing` as tasks of `client`, a bounded number in flight; write each once."""
    distributed = _dask()
    if not missing:
        return
    token = uuid.uuid4().hex[:12]
    todo = iter(missing)
    running = {}  # key -> (future, block)
    ac = distributed.as_completed()

    def top_up():  # two blocks per worker thread (workers may join or leave meanwhile)
        window = max(2, 2 * sum(client.nthreads().values()))
        while len(running) < window:
            b = next(todo, None)
            if b is None:
                return
            # the plan travels with each task (M x n x 5 floats: 240 kB at M = 1e3), not as
            # scattered data, which dies with the workers holding it
            f = client.submit(_run_block, plan, b, key=f"torchcal-sweep-{token}-{b}")
            running[f.key] = (f, b)
            ac.add(f)

    try:
        top_up()
        for f in ac:
            rows, stats = f.result()
            write(running.pop(f.key)[1], rows, stats)
            f.release()
            top_up()
    finally:
        if running:  # stopped early: nothing more for the workers to do
            client.cancel([f for f, _ in running.values()])
