"""Tests of the sweep in blocks (torchcal.workflows.distributed.sweep_block,
torchcal.reliability.sweep_blocks.block_seed), its
streamed and resumable output (torchcal.workflows.distributed.run_sweep,
torchcal.io.sweep_blocks) and its runs on a Dask LocalCluster of 2 worker processes.

What is checked, and against what:

- block seeding: a sweep of at most one block is the plain hypercube of `seed`; block b
  of the in-process sweep equals `sweep_block(b)` and its points the hypercube of
  `block_seed(seed, b)`, bit for bit, whatever the threads;
- the streamed CSV (in this process and on the cluster) against `write_sweep` of the
  in-process `sweep`: the same bytes; the merged summary against `SweepResult.summary()`;
- resume: a run stopped after k blocks, then run again: only the n - k missing blocks are
  computed (once each), the final file the same bytes; other arguments over a partial
  output refuse (one InputError naming what differs) unless force;
- a worker process killed mid-run (SIGKILL): its tasks run again elsewhere, every block
  reaches the output exactly once, the same bytes;
- without Dask, --scheduler gives one line naming the extra; --workers N needs no Dask (N
  threads of this process), the same bytes; blocks on spawned processes
  (`run_in_processes`) give the rows of this process.

The cluster tests share one LocalCluster (2 processes, 1 thread each); a watchdog
(faulthandler) ends the test process if a cluster start, run or shutdown hangs.
"""

from __future__ import annotations

import builtins
import faulthandler
import os
import signal
import sys

import numpy as np
import pytest
import torch

import torchcal
from torchcal import cli
from torchcal.errors import InputError, OutputExistsError
from torchcal.io.sweep_csv import sweep_csv_text
from torchcal.workflows.distributed import _hist_median, plan_sweep, run_sweep
from torchcal.reliability.sweep import sweep, sweep_states
from torchcal.reliability.sweep_blocks import block_seed
from torchcal.workflows.distributed import sweep_block
from torchcal.robots.workspace import sample_workspace

N, M, BLOCK = 700, 40, 100  # 7 blocks
WATCHDOG_S = 120


@pytest.fixture(scope="module")
def reference(kr):
    """The in-process sweep of N points in blocks of BLOCK, and its CSV text."""
    r = sweep(kr, n_points=N, n_samples=M, seed=5, block=BLOCK)
    return r, sweep_csv_text(r)


def _plan(kr, **kw):
    args = dict(n_points=N, n_samples=M, seed=5, block=BLOCK)
    args.update(kw)
    return plan_sweep(kr, **args)


class Stop(Exception):
    pass


# -- block seeding ----------------------------------------------------------------------------
def test_one_block_is_the_plain_hypercube_of_the_seed(kr):
    r = sweep(kr, n_points=30, n_samples=20, seed=4)
    assert torch.equal(r.q, sample_workspace(kr, 30, seed=4))


def test_blocks_are_seeded_by_their_index(kr, reference):
    r, _ = reference
    dev, box = sweep_states(kr, n_samples=M, seed=5)
    for b in (0, 3, 6):
        a0, a1 = b * BLOCK, min(N, (b + 1) * BLOCK)
        assert torch.equal(r.q[a0:a1], sample_workspace(kr, a1 - a0, seed=block_seed(5, b)))
        for threads in (1, 3):
            blk = sweep_block(kr, b, n_points=N, deviations=dev, dev_box=box, seed=5, block=BLOCK, threads=threads)
            assert torch.equal(blk.point, torch.arange(a0, a1))
            for name in ("q", "positions", "err_lower", "err_upper", "dist_upper", "eta", "r_set", "lin_upper"):
                assert torch.equal(getattr(blk, name), getattr(r, name)[a0:a1]), (b, threads, name)
    # distinct blocks draw distinct points
    assert not torch.equal(r.q[:BLOCK], r.q[BLOCK:2 * BLOCK])


def test_histogram_median_against_numpy():
    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 1000):
        x = rng.random(n)
        x[: n // 3] = 1.0
        hist = np.histogram(x[x < 1], 10_000, (0.0, 1.0))[0]
        assert abs(_hist_median(hist, 0.0, 1.0, int((x >= 1).sum())) - np.median(x)) <= 1e-4


# -- streamed, resumable, in this process -------------------------------------------------------
def test_streamed_equals_in_process_and_summary(kr, reference, tmp_path):
    r, text = reference
    out = tmp_path / "s.csv"
    seen = []
    s = run_sweep(_plan(kr), out, on_block=seen.append)
    assert out.read_text() == text
    assert sorted(seen) == list(range(7))
    assert not (tmp_path / "s.csv.blocks").exists()
    ref = r.summary()
    for k in ("points", "r_set_min", "r_set_max", "share_r_set_1", "dist_upper_min_mm", "dist_upper_max_mm",
              "linear_ratio_max"):
        assert s[k] == pytest.approx(ref[k], rel=0, abs=1e-15), k
    for k in ("r_set_median", "linear_ratio_median"):
        assert abs(s[k] - ref[k]) <= 1e-4, k


def _stop_after(k, seen):
    def hook(b):
        seen.append(b)
        if len(seen) == k:
            raise Stop
    return hook


def test_resume_computes_only_the_missing_blocks(kr, reference, tmp_path):
    out = tmp_path / "s.csv"
    first = []
    with pytest.raises(Stop):
        run_sweep(_plan(kr), out, on_block=_stop_after(3, first))
    assert not out.exists()
    assert len(list((tmp_path / "s.csv.blocks").glob("block-*.csv"))) == 3
    # a write cut short by a kill leaves a temporary file, never a block: it is cleared
    (tmp_path / "s.csv.blocks" / ".block-000005.csv.x1y2.tmp").write_text("0,1,2\n")
    lines, second = [], []
    s = run_sweep(_plan(kr), out, on_block=second.append, log=lines.append)
    assert len(lines) == 1 and "3 of 7 blocks already done" in lines[0] and "the 4 missing" in lines[0]
    assert sorted(first + second) == list(range(7))  # each block computed once
    assert out.read_text() == reference[1]
    assert not (tmp_path / "s.csv.blocks").exists() and len(list(tmp_path.iterdir())) == 1
    ref = reference[0].summary()  # the blocks done before count in the summary
    assert s["points"] == N and s["r_set_min"] == ref["r_set_min"] and s["share_r_set_1"] == ref["share_r_set_1"]


def test_other_arguments_over_a_partial_output_refuse(kr, tmp_path):
    out = tmp_path / "s.csv"
    with pytest.raises(Stop):
        run_sweep(_plan(kr), out, on_block=_stop_after(2, []))
    refusal = r"partial sweep with other arguments \(clearance states differ; seed 5 there, 6 here\); rerun with the same arguments"
    with pytest.raises(OutputExistsError, match=refusal):  # the command line adds its --force hint
        run_sweep(_plan(kr, seed=6), out)
    with pytest.raises(InputError, match=r"samples 40 there, 41 here"):
        run_sweep(_plan(kr, n_samples=41), out)
    assert len(list((tmp_path / "s.csv.blocks").glob("block-*.csv"))) == 2  # untouched
    seen = []
    run_sweep(_plan(kr, seed=6, n_points=250), out, force=True, on_block=seen.append)
    assert sorted(seen) == [0, 1, 2]  # started over
    assert out.read_text() == sweep_csv_text(sweep(kr, n_points=250, n_samples=M, seed=6, block=BLOCK))


def test_cli_resume_says_so_in_one_line(tmp_path, capsys):
    out = tmp_path / "s.csv"
    argv = ["sweep", "--n", "250", "--samples", "30", "--block", "100", "--out", str(out), "--no-progress"]
    from torchcal.io.sweep_blocks import BlockFolder

    assert cli.main(argv) == 0
    full = out.read_text()
    out.unlink()
    # a partial output: the folder of a run killed after block 1
    plan = plan_sweep(torchcal.robot("kr1000titan"), n_points=250, n_samples=30, block=100)
    folder = BlockFolder(out)
    folder.open(plan.manifest())
    folder.write(1, *plan.compute(1))
    capsys.readouterr()
    assert cli.main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln for ln in lines if "resuming" in ln] == [
        f"sweep: resuming {out}: 1 of 3 blocks already done in {out}.blocks, computing the 2 missing"]
    assert out.read_text() == full


def test_cli_without_dask_names_the_extra(tmp_path, monkeypatch, capsys):
    real = builtins.__import__

    def no_dask(name, *a, **kw):
        if name == "dask" or name.startswith("dask."):
            raise ImportError(f"No module named {name!r}")
        return real(name, *a, **kw)

    monkeypatch.setattr(builtins, "__import__", no_dask)
    out = tmp_path / "s.csv"
    assert cli.main(["sweep", "--n", "10", "--out", str(out), "--no-progress", "--scheduler", "tcp://127.0.0.1:1"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "pip install 'torchcal[distributed]'" in err
    assert not out.exists() and not (tmp_path / "s.csv.blocks").exists()
    # --workers: threads of this process, no Dask needed
    assert cli.main(["sweep", "--n", "10", "--out", str(out), "--no-progress", "--workers", "2"]) == 0


def test_cli_workers_equal_in_process(tmp_path, capsys):
    """--workers N: N threads of this process (no cluster), the CSV byte for byte that of
    the default run."""
    argv = ["sweep", "--n", "250", "--samples", "30", "--block", "100", "--no-progress"]
    assert cli.main(argv + ["--out", str(tmp_path / "a.csv")]) == 0
    assert cli.main(argv + ["--out", str(tmp_path / "b.csv"), "--workers", "2"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1] == out[4]  # the same summary
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


def test_run_in_processes_writes_each_block_once(kr):
    """`run_sweep(processes=N)`'s engine: blocks on spawned processes, each written once,
    the rows those of this process."""
    from torchcal.workflows import distributed as D

    plan = D.plan_sweep(kr, n_points=250, n_samples=20, block=100)
    got = []
    D.run_in_processes(plan, [0, 1, 2], lambda b, rows, stats: got.append((b, rows)), 2)
    assert sorted(b for b, _ in got) == [0, 1, 2]
    assert dict(got)[1] == plan.compute(1)[0]  # block 1's rows, as computed in this process


# -- on a LocalCluster of 2 worker processes -----------------------------------------------------
@pytest.fixture()
def watchdog():
    faulthandler.dump_traceback_later(WATCHDOG_S, exit=True, file=sys.__stderr__)  # a hung cluster ends the process
    yield
    faulthandler.cancel_dump_traceback_later()


@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("dask.distributed")
    faulthandler.dump_traceback_later(WATCHDOG_S, exit=True, file=sys.__stderr__)
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=":0", worker_class=distributed.Nanny,
                                       preload=["torchcal.threads"])  # as connect(workers=N) starts them
    c = distributed.Client(cluster, timeout=60)
    c.wait_for_workers(2, timeout=60)
    faulthandler.cancel_dump_traceback_later()
    yield c
    faulthandler.dump_traceback_later(WATCHDOG_S, exit=True, file=sys.__stderr__)
    c.close(timeout=30)
    cluster.close(timeout=30)
    faulthandler.cancel_dump_traceback_later()


def test_cluster_equals_in_process(kr, reference, client, tmp_path, watchdog):
    out = tmp_path / "s.csv"
    seen = []
    s = run_sweep(_plan(kr), out, client=client, on_block=seen.append)
    assert sorted(seen) == list(range(7))
    assert out.read_text() == reference[1]  # bit for bit (floats written exactly)
    assert s["r_set_min"] == reference[0].summary()["r_set_min"]
    assert len({a for a in client.run(os.getpid).values()}) == 2  # two worker processes


def test_cluster_resume_after_a_stopped_run(kr, reference, client, tmp_path, watchdog):
    out = tmp_path / "s.csv"
    first, second = [], []
    with pytest.raises(Stop):
        run_sweep(_plan(kr), out, client=client, on_block=_stop_after(2, first))
    done = sorted(int(f.stem[6:]) for f in (tmp_path / "s.csv.blocks").glob("block-*.csv"))
    assert done == sorted(first)
    lines = []
    run_sweep(_plan(kr), out, client=client, on_block=second.append, log=lines.append)
    assert len(lines) == 1 and "2 of 7 blocks already done" in lines[0]
    assert sorted(first + second) == list(range(7)) and not set(first) & set(second)
    assert out.read_text() == reference[1]


def test_cluster_worker_lost_mid_run(kr, client, tmp_path, watchdog):
    """SIGKILL a worker process holding tasks: they are run again, each block written once."""
    plan = _plan(kr, n_points=1200, n_samples=200, block=100)  # 12 blocks
    ref = sweep_csv_text(sweep(kr, n_points=1200, n_samples=200, seed=5, block=100))
    pids = client.run(os.getpid)  # worker address -> process id
    killed = {}
    seen = []

    def hook(b):
        seen.append(b)
        if not killed:
            busy = {w: keys for w, keys in client.processing().items() if keys}
            if not busy:  # a loaded machine: the scheduler may not have handed out the next
                return    # blocks yet; kill at a later block
            addr = max(busy, key=lambda w: len(busy[w]))
            killed["keys"] = list(busy[addr])
            os.kill(pids[addr], signal.SIGKILL)

    out = tmp_path / "s.csv"
    run_sweep(plan, out, client=client, on_block=hook)
    assert killed["keys"]  # the killed worker held tasks, which were then run elsewhere
    assert sorted(seen) == list(range(12))  # every block written, none twice
    assert out.read_text() == ref
    client.wait_for_workers(2, timeout=60)  # the nanny restarted it
    assert set(client.run(os.getpid).values()) != set(pids.values())


def test_cli_scheduler_address(kr, client, tmp_path, watchdog):
    """--scheduler ADDRESS: the blocks are tasks of that cluster (the fixture's); the same CSV."""
    from dask.distributed import get_task_stream

    out = tmp_path / "s.csv"
    argv = ["sweep", "--n", "250", "--samples", "30", "--block", "100", "--no-progress", "--out", str(out)]
    with get_task_stream(client) as ts:
        assert cli.main(argv + ["--scheduler", client.scheduler.address]) == 0
    blocks = sorted(int(t["key"].rsplit("-", 1)[1]) for t in ts.data
                    if str(t["key"]).startswith("torchcal-sweep-"))
    assert blocks == [0, 1, 2]
    assert out.read_text() == sweep_csv_text(sweep(kr, n_points=250, n_samples=30, block=100))
