"""The thread policy on a busy machine: FK and `discover`, quiet and under load.

Each workload runs in a fresh subprocess (torch's default thread count, the cores, and
torchcal's policy, `torchcal.threads`: OMP_WAIT_POLICY=PASSIVE, threads by problem
size, FK chunks handed to single-threaded workers), first on the machine as it is
("quiet"), then while --busy busy-loop processes that this script starts and stops
itself occupy the cores ("loaded"):

- FK: `Robot.fk` of the KR 1000 Titan, --poses poses x --sets perturbed MD-H tables,
  float64, median of --repeats calls (M pairs/s);
- discover: `torchcal.discover` on the UR10 series C training split (60/40 by pose,
  seed 0; base_frame + tool_offset), one call (s).

Target: loaded time <= 2.5x quiet. --baseline adds the same runs with OpenMP threads that
spin (OMP_WAIT_POLICY=ACTIVE, TORCHCAL_THREADS = the cores, the FK chunks run serially
with 2-thread ops), the behaviour the policy replaces. Timings on a shared machine are
noisy: the load average is printed with each figure.

    python benchmarks/bench_threads.py [--busy 2] [--repeats 5] [--baseline]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_RATIO = 2.5


def _fk_part(poses: int, sets: int, repeats: int, serial: bool) -> dict:
    import torch

    import torchcal
    from torchcal.kinematics import mdh as K

    robot = torchcal.robot("kr1000titan")
    g = torch.Generator().manual_seed(0)
    q = torch.rand(poses, robot.n, generator=g, dtype=torch.float64) * 2 - 1
    params = (torch.rand(sets, 1, robot.n, 5, generator=g, dtype=torch.float64) - 0.5) * 1e-3
    if serial:  # the old way: every chunk on the calling thread, ops split over all threads
        torch.set_num_threads(os.cpu_count())  # (the policy itself keeps one intra-op thread)
        fk = lambda: [K.positions(q, robot.chain, params[i:i + 64])  # noqa: E731
                      for i in range(0, sets, 64)]
    else:
        fk = lambda: robot.fk(q, params)  # noqa: E731
    fk()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fk()
        times.append(time.perf_counter() - t)
    return {"value": poses * sets / statistics.median(times) / 1e6, "unit": "M pairs/s",
            "threads": torch.get_num_threads()}


def _discover_part(folder: Path) -> dict:
    import torch

    import torchcal
    from torchcal.io.measurement_csv import read_measurements
    from torchcal.io.robot_file import load_robot_file

    robot = load_robot_file(ROOT / "examples" / "ur10" / "ur10.json")
    m = read_measurements(folder / "train.csv", robot=robot)
    t = time.perf_counter()
    torchcal.discover(robot, m, ["base_frame", "tool_offset"])
    return {"value": time.perf_counter() - t, "unit": "s", "threads": torch.get_num_threads()}


def _run(part: str, args, folder: Path, baseline: bool) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("OMP_NUM_THREADS", None)
    env.pop("TORCHCAL_THREADS", None)
    if baseline:
        env.update(OMP_WAIT_POLICY="ACTIVE", TORCHCAL_THREADS=str(os.cpu_count()))
    cmd = [sys.executable, __file__, "--part", part, "--folder", str(folder), "--poses", str(args.poses),
           "--sets", str(args.sets), "--repeats", str(args.repeats)] + (["--serial"] if baseline else [])
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if out.returncode != 0:
        raise SystemExit(f"{part} failed:\n{out.stderr[-3000:]}")
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["load"] = round(os.getloadavg()[0], 2)
    return res


def _busy(n: int) -> list:
    """n busy-loop processes (stopped by `_stop`)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def _stop(procs) -> None:
    for p in procs:
        p.kill()
        p.wait()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--busy", type=int, default=2, help="busy-loop processes of the loaded runs (default 2)")
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--sets", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=5, help="FK calls timed, median (default 5)")
    ap.add_argument("--baseline", action="store_true", help="also time spinning OpenMP threads")
    ap.add_argument("--skip-discover", action="store_true")
    ap.add_argument("--part", help=argparse.SUPPRESS)
    ap.add_argument("--folder", help=argparse.SUPPRESS)
    ap.add_argument("--serial", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.part:
        res = (_fk_part(args.poses, args.sets, args.repeats, args.serial) if args.part == "fk"
               else _discover_part(Path(args.folder)))
        print(json.dumps(res))
        return 0

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_fit import split

    parts = ["fk"] + ([] if args.skip_discover else ["discover"])
    policies = [("torchcal policy", False)] + ([("spinning threads", True)] if args.baseline else [])
    print(f"cores {os.cpu_count()}, busy loops {args.busy}, load at start {os.getloadavg()[0]:.2f}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        split(folder)
        for label, baseline in policies:
            for part in parts:
                quiet = _run(part, args, folder, baseline)
                procs = _busy(args.busy)
                try:
                    time.sleep(0.5)
                    loaded = _run(part, args, folder, baseline)
                finally:
                    _stop(procs)
                rows.append((label, part, quiet, loaded))
    print(f"\n{'policy':18s} {'workload':9s} {'quiet':>16s} {'loaded':>16s} {'slow-down':>10s}  target <= {TARGET_RATIO}x")
    for label, part, quiet, loaded in rows:
        q, lo = quiet["value"], loaded["value"]
        ratio = q / lo if quiet["unit"] != "s" else lo / q
        unit = quiet["unit"]
        print(f"{label:18s} {part:9s} {q:9.2f} {unit:>6s} {lo:9.2f} {unit:>6s} {ratio:9.2f}x  "
              f"{'met' if ratio <= TARGET_RATIO else 'MISSED'}  (load {quiet['load']} / {loaded['load']}, "
              f"{quiet['threads']} torch threads)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
