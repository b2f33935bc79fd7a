"""Start-up cost of the command line: CPU seconds of whole commands, as a user runs them.

    python benchmarks/bench_startup.py [--repeats 5]

Each command runs in a fresh process (`python -m torchcal ...`, the default thread
policy); its CPU time (user + system of the child, from getrusage) and wall time are the
medians over --repeats runs. Rows: `python -c pass` (the interpreter), `import torch`
(the floor of any command that computes), `torchcal --help`, every sub-command's
``--help``, and `torchcal fit` of the UR10 series C training split (examples/ur10,
60/40 by pose, seed 0; --effects base_frame tool_offset). Targets: a
sub-command's --help under 0.3 s, the fit at most 1.5 s CPU. The load average is printed:
on a shared machine it moves every figure.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HELP_TARGET_S, FIT_TARGET_S = 0.3, 1.5


def timed(argv: list[str], repeats: int) -> tuple[float, float]:
    """Median (wall s, cpu s) of `argv` run `repeats` times."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    walls, cpus = [], []
    for _ in range(repeats):
        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        walls.append(time.perf_counter() - t0)
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(c1.ru_utime - c0.ru_utime + c1.ru_stime - c0.ru_stime)
    return statistics.median(walls), statistics.median(cpus)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    from torchcal.cli import COMMANDS

    py, tc = sys.executable, [sys.executable, "-m", "torchcal"]
    print(f"start-up, median of {a.repeats} runs; load average {os.getloadavg()[0]:.1f} at the start")
    print(f"{'command':<44} {'wall s':>8} {'cpu s':>8} {'x pass':>8}")
    _, base = timed([py, "-c", "pass"], a.repeats)

    def row(name, argv, target=None):
        w, c = timed(argv, a.repeats)
        note = "" if target is None else f"  target {target:g} s: {'met' if c <= target else 'missed'}"
        print(f"{name:<44} {w:>8.3f} {c:>8.3f} {c / max(base, 1e-3):>8.0f}{note}", flush=True)
        return c

    row("python -c pass", [py, "-c", "pass"])
    torch_cpu = row("python -c 'import torch'", [py, "-c", "import torch"])
    row("torchcal --help", tc + ["--help"], HELP_TARGET_S)
    for cmd in COMMANDS:
        row(f"torchcal {cmd} --help", tc + [cmd, "--help"], HELP_TARGET_S)
    with tempfile.TemporaryDirectory() as tmp:
        train, val = f"{tmp}/c_train.csv", f"{tmp}/c_val.csv"
        subprocess.run([py, str(ROOT / "examples/ur10/split.py"), str(ROOT / "examples/ur10/series_c.csv"),
                        train, val, "--fraction", "0.6", "--seed", "0"], check=True, stdout=subprocess.DEVNULL)
        fit = row("torchcal fit (series C train, 1664 rows)",
                  tc + ["fit", train, "--robot", str(ROOT / "examples/ur10/ur10.json"), "--effects", "base_frame",
                        "tool_offset", "--out", f"{tmp}/m.json", "--force"], FIT_TARGET_S)
    print(f"fit - import torch: {fit - torch_cpu:.3f} s cpu (torchcal's own imports, reading, the fit, writing); "
          f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
