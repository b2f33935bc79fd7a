"""`torchcal simulate`: a measurement session of a virtual robot (the measurement CSV of docs/formats.md).

    torchcal simulate --robot kr1000titan --effects joint_compliance:2,3 thermal_expansion \\
        --n 60 --repeats 3 --noise 0.02 --seed 0 --out data.csv [--truth truth.json]

Draws N random poses inside the joint limits (seed P), builds a `torchcal.simulation.virtual_robot.VirtualRobot`
with hidden geometric deviations and the chosen effects (seed S), measures each pose K
times with isotropic Gaussian noise of MM mm (1 sigma per axis; session seed P) and writes
the CSV atomically (an existing file is only replaced with --force). The session writes the
``payload_kg`` / ``temp_c`` columns when an effect depends on them. The same arguments
give a byte-identical file.

``--pose-seed P`` (default: S) draws fresh poses and a fresh session of the same simulated
robot: ``--seed 0 --out train.csv`` and ``--seed 0 --pose-seed 1 --out test.csv`` are a
training and a held-out set of one robot; ``--seed 1`` is another robot.

``--truth FILE`` writes the true parameters as JSON: ``{"robot", "seed", "effects",
"parameters": {name: {"value", "unit"}}}`` with values in the units of MODEL.json (mm,
deg, ...; `torchcal.io.modelfile.file_unit`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from torchcal.cli._args import (seed_int, add_effects_module, add_force, check_outputs, positive_int, nonneg_float, add_robot,
                                robot_inputs)


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("simulate", help="simulate a measurement session of a virtual robot (CSV)",
                       description=__doc__.splitlines()[0])
    add_robot(p, required=False, default="kr1000titan", what="the virtual robot")
    p.add_argument("--effects", nargs="*", default=[], metavar="SPEC",
                   help="physical effects of the virtual robot, NAME or NAME:J[,J...]")
    p.add_argument("--n", type=positive_int, default=50, help="number of poses N (default 50)")
    p.add_argument("--repeats", type=positive_int, default=1,
                   help="measurements per pose K (default 1)")
    p.add_argument("--noise", type=nonneg_float, default=0.02,
                   help="measurement noise, mm (1 sigma per axis; default 0.02)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the simulated robot and, without "
                   "--pose-seed, of the poses and the session (default 0)")
    p.add_argument("--pose-seed", type=seed_int, default=None, metavar="P",
                   help="seed of the poses and the measurement session (default: --seed); another P: "
                        "fresh poses of the same robot")
    p.add_argument("--out", required=True, help="output measurement CSV")
    p.add_argument("--truth", default=None, help="also write the true parameters (JSON)")
    add_force(p)
    add_effects_module(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from torchcal.api import simulate
    from torchcal.io.files import write_json
    from torchcal.io.measurement_csv import write_measurements
    from torchcal.io.truth_file import truth_to_dict

    check_outputs([("--out", args.out), ("--truth", args.truth)], args.force, inputs=robot_inputs(args.robot))
    out, truth = Path(args.out), Path(args.truth) if args.truth else None
    sim = simulate(args.robot, args.effects, n=args.n, repeats=args.repeats, noise_mm=args.noise, seed=args.seed,
                   pose_seed=args.pose_seed)
    write_measurements(out, sim.measurements, force=args.force, robot=sim.robot)
    if truth is not None:
        write_json(truth, truth_to_dict(sim), force=args.force, inputs=(out,))
    d = sim.to_dict()
    extra = f" (+ {', '.join(d['columns'])})" if d["columns"] else ""
    print(f"simulate: {d['robot']}, effects [{' '.join(d['effects']) or 'none'}], {args.n} poses x "
          f"{d['repeats']} repeats = {d['rows']} rows{extra}, noise {d['noise_mm']:g} mm, seed {d['seed']}"
          + (f", pose seed {d['pose_seed']}" if args.pose_seed is not None else "") + f"; wrote {out}"
          + (f", {truth} (truth)" if truth else ""))
    return 0
