"""`--device`: a clear refusal where CUDA is absent (runs everywhere), and the GPU path
checked against the CPU where a CUDA device is present (skipped elsewhere, with the reason).

- fit, discover, sweep and demo refuse ``--device cuda`` without CUDA in one line (exit 2),
  before any work and without writing anything; a device that is not cpu / cuda[:N] too;
- on a GPU: Robot.fk (its chunk per device), the approach directions, the sweep (a block
  and the streamed CSV's figures) and a fit of the UR10 series D agree with the CPU.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from torchcal import cli

ROOT = Path(__file__).resolve().parents[1]
DATA, UR10 = ROOT / "examples/ur10/series_d.csv", ROOT / "examples/ur10/ur10.json"
CUDA = torch.cuda.is_available()
needs_cuda = pytest.mark.skipif(not CUDA, reason="no CUDA device visible to torch (the GPU path needs one)")


@pytest.mark.skipif(CUDA, reason="CUDA is present: nothing to refuse")
@pytest.mark.parametrize("argv", [["fit", str(DATA), "--robot", str(UR10), "--out", "OUT"],
                                  ["discover", str(DATA), "--robot", str(UR10), "--out", "OUT"],
                                  ["sweep", "--n", "10", "--out", "OUT"],
                                  ["demo", "--json", "OUT"]])
def test_cuda_absent_is_one_line_and_nothing_written(argv, tmp_path, capsys):
    out = tmp_path / "out"
    argv = [str(out) if a == "OUT" else a for a in argv]
    assert cli.main(argv + ["--device", "cuda"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--device cuda: CUDA is not available" in err[0] and "--device cpu" in err[0]
    assert not list(tmp_path.iterdir())


def test_a_device_that_is_not_cpu_or_cuda_is_refused(tmp_path, capsys):
    assert cli.main(["sweep", "--n", "10", "--out", str(tmp_path / "s.csv"), "--device", "tpu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "expected cpu, cuda or cuda:N, got 'tpu'" in err[0]
    assert not list(tmp_path.iterdir())


def test_fk_chunk_follows_the_device():
    from torchcal.kinematics import mdh

    assert mdh.chunk_for("cpu") == mdh.DEFAULT_CHUNK
    assert mdh.chunk_for("cuda") == mdh.DEFAULT_CHUNK_GPU > mdh.DEFAULT_CHUNK
    # the in-place kernel's CPU chunk by dtype (float64: 8 rows of temporaries within a 2 MiB L2)
    assert 8 * 8 * mdh.chunk_for("cpu", torch.float64) <= 1 << 20
    assert mdh.chunk_for("cpu", torch.float32) == mdh.DEFAULT_CHUNK
    for dtype in (torch.float64, torch.float32):
        assert mdh.chunk_for("cuda", dtype) == mdh.DEFAULT_CHUNK_GPU


# -- on a GPU ------------------------------------------------------------------------------

@needs_cuda
def test_fk_on_cuda_matches_cpu(kr):
    g = torch.Generator().manual_seed(0)
    q = torch.rand(5000, 6, generator=g, dtype=torch.float64) * 2 - 1
    dev = (torch.rand(300, 6, 5, generator=g, dtype=torch.float64) - 0.5) * 1e-3
    cpu = kr.fk(q[:, None], dev[None])
    gpu = kr.to("cuda").fk(q.cuda()[:, None], dev.cuda()[None])
    assert gpu.device.type == "cuda"
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=0, atol=1e-9)


@needs_cuda
def test_approach_directions_on_cuda_match_cpu():
    from torchcal.effects.context import approach_directions

    g = torch.Generator().manual_seed(1)
    q = torch.randint(-2, 3, (500, 6), generator=g).double() * 0.1
    assert torch.equal(approach_directions(q.cuda()).cpu(), approach_directions(q))


@needs_cuda
def test_sweep_block_on_cuda_matches_cpu(kr):
    from torchcal.reliability.sweep import sweep_states
    from torchcal.workflows.distributed import sweep_block

    dev, box = sweep_states(kr, n_samples=50, seed=2)
    kw = dict(n_points=300, deviations=dev, dev_box=box, seed=2, block=300)
    cpu, gpu = sweep_block(kr, 0, **kw), sweep_block(kr, 0, device="cuda", **kw)
    assert gpu.dist_upper.device.type == "cuda"
    for name in ("err_lower", "err_upper", "dist_upper", "lin_dist_upper"):
        torch.testing.assert_close(getattr(gpu, name).cpu(), getattr(cpu, name), rtol=0, atol=1e-9)
    assert torch.equal(gpu.point.cpu(), cpu.point)


@needs_cuda
def test_cli_fit_and_sweep_on_cuda_match_cpu(tmp_path, capsys):
    import json

    fits = {}
    for d in ("cpu", "cuda"):
        out = tmp_path / f"{d}.json"
        assert cli.main(["fit", str(DATA), "--robot", str(UR10), "--effects", "base_frame", "tool_offset",
                         "--out", str(out), "--device", d]) == 0
        fits[d] = {p["name"]: p["value"] for p in json.loads(out.read_text())["parameters"]}
    assert fits["cpu"].keys() == fits["cuda"].keys()
    for k, v in fits["cpu"].items():
        assert abs(fits["cuda"][k] - v) <= 1e-6 * max(1.0, abs(v)), k
    for d in ("cpu", "cuda"):
        assert cli.main(["sweep", "--n", "300", "--samples", "40", "--block", "100", "--no-progress",
                         "--out", str(tmp_path / f"{d}.csv"), "--device", d]) == 0
    lines = capsys.readouterr().out.splitlines()
    summaries = [x for x in lines if x.startswith("R_set min")]
    assert len(summaries) == 2 and summaries[0] == summaries[1]


@needs_cuda
@pytest.mark.xfail(strict=True, reason="never run on a GPU: discover's diagnosis reads tensors to numpy with "
                                       ".numpy(force=True) (a copy to the CPU), but its numpy results meet device "
                                       "tensors again in places not yet read for it; remove this mark once a GPU "
                                       "runs it green")
def test_cli_discover_on_cuda_matches_cpu(tmp_path, capsys):
    import json

    found = {}
    for d in ("cpu", "cuda"):
        assert cli.main(["discover", str(DATA), "--robot", str(UR10), "--effects", "base_frame", "tool_offset",
                         "--json", str(tmp_path / f"{d}.json"), "--device", d]) == 0
        found[d] = json.loads((tmp_path / f"{d}.json").read_text())["final_effects"]
    assert found["cuda"] == found["cpu"]
