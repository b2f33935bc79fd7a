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

Then where the fit's CPU goes, median per phase over --repeats fresh processes that run
the command's steps one by one (the library calls `torchcal fit` makes): the interpreter,
`import torch` as the command line imports it (`torchcal.cli.import_torch`), torchcal's
own modules (and what they import) on the way to a fit, reading the CSV (with the unit
check), the fit, writing MODEL.json, and the interpreter's exit (the process's CPU time
less the rest). Each phase includes the imports it makes on first use.
"""

from __future__ import annotations

import argparse
import json
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


#: one fresh process: the steps of `torchcal fit`, CPU seconds at the end of each (JSON)
PHASES = """
import json, sys, time
t = {"interpreter": time.process_time()}
import torchcal.cli
torchcal.cli.import_torch()
t["import torch"] = time.process_time()
import torchcal, torchcal.api, torchcal.cli.fit, torchcal.effects.registry, torchcal.io.modelfile
from torchcal.calibration.checks.units import check_units
from torchcal.io.measurement_csv import read_measurements
t["torchcal imports"] = time.process_time()
data, robot_file, out = sys.argv[1:4]
robot = torchcal.robot(robot_file)
m = read_measurements(data, robot=robot)
check_units(m, robot, where=data)
t["read"] = time.process_time()
res = torchcal.fit(robot, m, ["base_frame", "tool_offset"])
t["fit"] = time.process_time()
torchcal.save(res, out, source=data, pose_ids=m.pose.tolist(), force=True)
t["write"] = time.process_time()
print(json.dumps(t))
"""


def phases(data: str, robot_file: str, out: str, repeats: int) -> dict:
    """Median CPU seconds per phase of the fit's steps (`PHASES`), exit included."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    runs = []
    for _ in range(repeats):
        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        done = subprocess.run([sys.executable, "-c", PHASES, data, robot_file, out], env=env, check=True,
                              capture_output=True, text=True)
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        marks = json.loads(done.stdout.splitlines()[-1])
        total = c1.ru_utime - c0.ru_utime + c1.ru_stime - c0.ru_stime
        names, ends = list(marks), list(marks.values())
        one = {names[0]: ends[0]} | {n: b - a for n, a, b in zip(names[1:], ends, ends[1:])}
        one["exit"] = total - ends[-1]
        one["total"] = total
        runs.append(one)
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


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
    row("python -c 'import torch'", [py, "-c", "import torch"])
    row("torchcal --help", tc + ["--help"], HELP_TARGET_S)
    for cmd in COMMANDS:
        row(f"torchcal {cmd} --help", tc + [cmd, "--help"], HELP_TARGET_S)
    with tempfile.TemporaryDirectory() as tmp:
        train, val = f"{tmp}/c_train.csv", f"{tmp}/c_val.csv"
        subprocess.run([py, str(ROOT / "examples/ur10/split.py"), str(ROOT / "examples/ur10/series_c.csv"),
                        train, val, "--fraction", "0.6", "--seed", "0"], check=True, stdout=subprocess.DEVNULL)
        ur10 = str(ROOT / "examples/ur10/ur10.json")
        fit = row("torchcal fit (series C train, 1664 rows)",
                  tc + ["fit", train, "--robot", ur10, "--effects", "base_frame",
                        "tool_offset", "--out", f"{tmp}/m.json", "--force"], FIT_TARGET_S)
        print(f"where the fit's CPU goes (its steps one by one, median of {a.repeats} processes):")
        split = phases(train, ur10, f"{tmp}/p.json", a.repeats)
        for name, cpu in split.items():
            print(f"  {name:<42} {cpu:>8.3f}")
    floor = split["interpreter"] + split["import torch"]
    print(f"torchcal fit {fit:.3f} s cpu; the interpreter and import torch (as the command imports it) "
          f"{floor:.3f} s, the rest {fit - floor:.3f} s (torchcal's imports, reading, the fit, writing, exit); "
          f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
