"""`torchcal compensate TARGETS.csv --model MODEL.json --out Q.csv`: corrected joint commands
that make the calibrated model reach each target (torchcal.calibration.compensate).

TARGETS.csv: header ``x,y,z`` (mm, robot base frame; --length-unit m for metres) and
optionally ``q1..qN`` (degrees, mm for a prismatic joint; --angle-unit rad, --length-unit m), ``payload_kg``
and ``temp_c`` (the conditions of each move, needed by load- and temperature-dependent effects):
the seed of each target, normally the command that nominally reaches it. Without seeds
the nominal inverse is solved first from a default seed (joint 1 turned towards the
target, the others at the middle of their limits).

MODEL.json: an interval model of ``torchcal calibrate`` (each target is assigned to a zone
by the partition's `assign` before anything is measured, and compensated with that
zone's center parameters) or a ``torchcal fit`` model (one parameter set).

Q.csv: ``point,zone,q1..qN,residual_mm,converged,within_limits`` with the corrected
commands in degrees, the calibrated model's remaining distance to the target (mm),
whether it met the tolerance and whether the command lies inside the joint limits; zones
are 1-based (1 for a single-set model). The file is written in full; when any target
did not converge or needs a command outside the limits, one stderr line names those
targets (1-based rows) and the command exits 1.
"""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

from torchcal.cli._args import add_effects_module, add_force, add_robot, add_units, check_outputs, load_robot
from torchcal.errors import InputError


def add_parser(sub):
    p = sub.add_parser("compensate", help="corrected joint commands for target positions",
                       description=__doc__.splitlines()[0])
    p.add_argument("targets", help="CSV with columns x,y,z (mm) [, q1..qN seeds in degrees]")
    p.add_argument("--model", required=True, help="MODEL.json (torchcal calibrate or torchcal fit)")
    p.add_argument("--out", required=True, help="output CSV of corrected joint commands (degrees)")
    add_robot(p, required=False, what="check that the model is for this robot (the model file embeds its robot)")
    add_units(p, "targets")
    add_force(p)
    add_effects_module(p)
    p.set_defaults(func=run)
    return p


def read_targets(path, n: int, length_unit: str = "mm", angle_unit: str = "deg", prismatic=None):
    """(targets (M, 3) mm, seeds (M, n) deg (mm for a prismatic joint) or None, extra
    {"payload_kg", "temp_c": (M,) or None}) from the CSV; InputError naming line and column.

    prismatic: optional (n,) bool; those seed columns are lengths in `length_unit`, the
    others angles in `angle_unit`."""
    import torch

    from torchcal.io.measurement_csv import LENGTH_UNITS

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: targets file does not exist")
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise InputError(f"{path}: empty file; expected a header x,y,z[,q1..q{n}]")
    header = [h.strip() for h in rows[0]]
    qcols = [f"q{k}" for k in range(1, n + 1)]
    for c in ("x", "y", "z"):
        if c not in header:
            raise InputError(f"{path}: header has no column {c!r}; expected x,y,z[,q1..q{n}], got {','.join(header)}")
    has_q = any(h.startswith("q") for h in header)
    if has_q and not all(c in header for c in qcols):
        missing = [c for c in qcols if c not in header]
        raise InputError(f"{path}: seed columns incomplete: missing {','.join(missing)} (expected q1..q{n} in degrees)")
    opt = [c for c in ("payload_kg", "temp_c") if c in header]
    unknown = [h for h in header if h not in ("x", "y", "z", "point", "payload_kg", "temp_c", *qcols)]
    if unknown:
        raise InputError(f"{path}: unknown column(s) {','.join(unknown)}; "
                         f"expected x,y,z[,q1..q{n}][,payload_kg][,temp_c]")
    extra = {c: [] for c in opt}
    slides = [False] * n if prismatic is None else [bool(p) for p in prismatic]
    idx = {h: i for i, h in enumerate(header)}
    xyz, qs = [], []
    for line, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise InputError(f"{path}: line {line}: expected {len(header)} columns, got {len(row)}")

        def num(col, unit):
            cell = row[idx[col]].strip()
            try:
                v = float(cell)
            except ValueError:
                raise InputError(f"{path}: line {line}, column {col}: expected a number ({unit}), got {cell!r}") from None
            if not math.isfinite(v):
                raise InputError(f"{path}: line {line}, column {col}: expected a finite number ({unit}), got {cell!r}")
            return v
        xyz.append([num(c, length_unit) for c in ("x", "y", "z")])
        if has_q:
            qs.append([num(c, length_unit if p else ("degrees" if angle_unit == "deg" else "rad"))
                       for c, p in zip(qcols, slides)])
        for c in opt:
            v = num(c, "kg" if c == "payload_kg" else "degC")
            if c == "payload_kg" and v < 0:
                raise InputError(f"{path}: line {line}, column payload_kg: payload must be >= 0 kg, got {v}")
            extra[c].append(v)
    if not xyz:
        raise InputError(f"{path}: no target rows")
    t = torch.tensor(xyz, dtype=torch.float64) * LENGTH_UNITS[length_unit]
    seeds = None
    if has_q:
        seeds = torch.tensor(qs, dtype=torch.float64)
        if angle_unit == "rad":
            seeds = torch.rad2deg(seeds)
        if prismatic is not None:  # a slide's seed is a length, never an angle
            pris = torch.as_tensor(prismatic, dtype=torch.bool).cpu()
            seeds = torch.where(pris, torch.tensor(qs, dtype=torch.float64) * LENGTH_UNITS[length_unit], seeds)
    cond = {c: (torch.tensor(extra[c], dtype=torch.float64) if c in extra else None)
            for c in ("payload_kg", "temp_c")}
    return t, seeds, cond


def load_model(path):
    """An `IntervalModel` from a calibrate MODEL.json or a fit MODEL.json (one zone)."""
    from torchcal.io import modelfile
    from torchcal.calibration.intervals import IntervalModel
    from torchcal.io.interval_model import INTERVAL_MODEL_FORMAT, interval_model_from_dict
    from torchcal.io.files import read_json

    obj = read_json(path, "model file")
    if obj.get("format") == INTERVAL_MODEL_FORMAT:
        return interval_model_from_dict(obj, str(path))
    fitted = modelfile.load(path)
    theta = fitted.theta
    return IntervalModel(fitted.model, theta[None], theta[None], theta[None], fitted.report.free[None],
                         [{"zone": 1, "level": None, "poses": None, "held": [], "rms_mm": fitted.training_rms_mm,
                           "damping": 0.0}], None, "fit", q_range=fitted.q_range,
                         residual_model=fitted.residual_model)


def run(args) -> int:
    from torchcal.api import compensate
    from torchcal.calibration.compensate import nominal_start
    from torchcal.calibration.joint_range import CalibratedRangeWarning
    from torchcal.cli._args import warnings_to_stderr
    from torchcal.io.files import atomic_write

    check_outputs([("--out", args.out)], args.force, inputs=[args.targets, args.model])
    im = load_model(args.model)
    robot = im.model.robot
    from torchcal.cli._args import units
    from torchcal.effects import make_context
    from torchcal.robots.robot_file import check_same_robot

    check_same_robot(robot, load_robot(args.robot), str(args.model))
    targets, seeds_deg, cond = read_targets(args.targets, robot.n, **units(args), prismatic=robot.prismatic)
    # the model's effects must find what they read (temp_c, payload_kg) in the targets
    probe = make_context(robot, robot.limits.mean(-1).expand(targets.shape[0], robot.n),
                         cond["payload_kg"], cond["temp_c"])
    for e in im.model.effects:
        try:
            e.check_context(probe)
        except InputError as exc:
            need = "column temp_c" if e.name == "thermal_expansion" else str(exc)
            raise InputError(f"{args.targets}: the model's effect {e.spec()} needs {need} "
                             f"in the targets, which they lack") from None
    from torchcal.calibration.mismatch import MismatchWarning, check_targets
    import warnings
    with warnings.catch_warnings():  # metres read as mm: refused; beyond the reach: named in the failure line
        warnings.simplefilter("ignore", MismatchWarning)
        far = check_targets(im.model, im.theta[0], targets, where=str(args.targets))
    if seeds_deg is None:
        q0 = nominal_start(robot, targets, where=str(args.targets))
    else:
        q0 = robot.q_from_user(seeds_deg)  # deg, mm for a prismatic joint
    # converged solutions outside the calibrated joint range: one warning line
    with warnings_to_stderr(CalibratedRangeWarning):
        comp = compensate(im, targets, q0, check=False, payload_kg=cond["payload_kg"], temp_c=cond["temp_c"])
    zone = im.assign(targets)  # the zone each target was compensated in (for Q.csv)
    qd = robot.q_to_user(comp.q)
    res = comp.residual_mm.norm(dim=-1)
    lines = [",".join(["point", "zone", *(f"q{k}" for k in range(1, robot.n + 1)), "residual_mm", "converged",
                       "within_limits"])]
    for i in range(targets.shape[0]):
        lines.append(",".join([str(i + 1), str(int(zone[i])), *("%.15g" % v for v in qd[i].tolist()),
                               repr(float(res[i])), str(bool(comp.converged[i])).lower(),
                               str(bool(comp.within_limits[i])).lower()]))
    atomic_write(args.out, "\n".join(lines) + "\n", force=args.force, inputs=[args.targets, args.model])
    bad_conv = (~comp.converged).nonzero().flatten().tolist()
    out_lim = (~comp.within_limits).nonzero().flatten().tolist()
    ok = targets.shape[0] - len(set(bad_conv) | set(out_lim))
    print(f"compensated {targets.shape[0]} targets with {im.n_zones} parameter set(s) ({im.method}): "
          f"{ok} converged within the joint limits; max predicted residual {float(res.max()):.3g} mm; "
          f"wrote {args.out}")
    if bad_conv or out_lim:
        def rows(ix):
            return ", ".join(map(str, [i + 1 for i in ix][:20])) + (" ..." if len(ix) > 20 else "")
        parts = ([f"not converged: target(s) {rows(bad_conv)}"] if bad_conv else []) + \
                ([f"outside the joint limits: target(s) {rows(out_lim)}"] if out_lim else []) + \
                ([f"beyond the reach of {robot.name}: target(s) {rows(far)}"] if far else [])
        sys.stderr.write(f"torchcal compensate: error: {len(set(bad_conv) | set(out_lim))} target(s) failed "
                         f"({'; '.join(parts)}); see {args.out}\n")
        return 1
    return 0
