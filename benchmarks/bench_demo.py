"""Time `torchcal demo` over seeds and print the figures (no asserts).

    python benchmarks/bench_demo.py [--seeds K] [--discover-rounds R] [--control] [--json OUT]

Default: the default `DemoConfig` over 10 seeds (the issue's benchmark). ``--control``:
the same robot without unmodelled position-dependent error (truth = MD-H + measurement
frame, clearance fully random), for docs/demo.md's "when does partitioning help".
"""

import argparse
import dataclasses
import time

from torchcal.cli._report import format_report
from torchcal.io.files import write_json
from torchcal.workflows.paper_config import DemoConfig
from torchcal.workflows.paper_experiment import run_demo


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--discover-rounds", type=int, default=DemoConfig.discover_rounds)
    p.add_argument("--control", action="store_true")
    p.add_argument("--json")
    a = p.parse_args()
    cfg = DemoConfig(discover_rounds=a.discover_rounds)
    if a.control:
        cfg = dataclasses.replace(cfg, truth_effects=("base_frame", "joint_clearance:1,2,3,4,5,6"),
                                  clearance_random=1.0)
    t0 = time.perf_counter()
    run = run_demo(cfg, seeds=a.seeds)
    dt = time.perf_counter() - t0
    print(format_report(run))
    print(f"\nbench_demo: {a.seeds} seeds in {dt:.1f} s ({dt / a.seeds:.1f} s per seed; "
          f"discover_rounds={cfg.discover_rounds}, control={a.control})")
    if a.json:
        write_json(a.json, run.to_json(), force=True)


if __name__ == "__main__":
    main()
