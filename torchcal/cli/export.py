"""`torchcal export MODEL.json [--robot-file OUT.json] [--urdf OUT.urdf] [--table OUT.csv]`:
the calibrated geometry for a controller or a simulator.

- ``--robot-file``: a robot file (docs/robots.md): nominal MD-H table + identified
  deviations, the ``base_frame`` effect folded into ``base``, ``tool_offset`` into ``tool``.
- ``--urdf``: a URDF whose joint origins carry the calibration. A robot imported from a
  URDF (``torchcal robot import``) keeps that file's links, inertias and visuals: its joint
  origins and axes are rewritten (torchcal.robots.urdf.calibrated_urdf); otherwise a
  minimal URDF (links base_link, link1..linkN, tcp; `minimal_urdf`).
- ``--table``: CSV ``joint,type,theta_offset_deg,d_mm,a_mm,alpha_deg,beta_deg,lower,upper``.

Effects a URDF or an MD-H table cannot hold (compliance, backlash, gear, thermal...): the
model's MD-H deviations were fitted together with them and absorbed part of them, so its
geometry alone is worse than the best geometry-only robot. With ``--data DATA.csv`` the
geometry alone is refitted on DATA, starting from the model
(torchcal.calibration.geometry_only), that geometry is exported, and one line gives the
RMS on DATA of the exported robot alone, of the full model and of the model's geometry
without its effects. Without ``--data`` the effects are listed in the robot file under
``"effects"`` with their values and one line says that the exported geometry alone is
worse and that by how much cannot be told without data.
The model's first parameter set is exported (zone 1 of an interval model).
"""

from __future__ import annotations

import math
import sys

from torchcal.cli._args import add_force, add_units, check_outputs



def add_parser(sub):
    p = sub.add_parser("export", help="calibrated geometry as a robot file, a URDF or an MD-H table",
                       description=__doc__.splitlines()[0])
    p.add_argument("model", metavar="MODEL.json", help="model of torchcal fit / discover / calibrate")
    p.add_argument("--robot-file", help="write the calibrated robot file (.json) here")
    p.add_argument("--urdf", help="write the calibrated URDF here")
    p.add_argument("--table", help="write the calibrated MD-H table (CSV, deg and mm) here")
    p.add_argument("--data", help="measurement CSV: refit the geometry alone on it when the model has effects "
                                  "a URDF cannot hold (best: the calibration data)")
    add_units(p)
    add_force(p)
    p.set_defaults(func=run)
    return p


def calibrated_robot(model, theta):
    """(Robot with the geometry folded in, [effect dicts not folded]) of a model and theta (P,)."""
    import dataclasses

    import torch

    from torchcal.rotations import rotvec_to_matrix

    r = model.robot.to("cpu", torch.float64)
    theta = theta.to("cpu", torch.float64)
    geo = theta[model.slices[0]].reshape(r.n, 5)
    base, tool = r.base.clone(), r.tool.clone()
    rest = []
    for e, sl in zip(model.effects, model.slices[1:]):
        p = theta[sl]
        if e.name == "base_frame":
            W = torch.eye(4, dtype=torch.float64)
            W[:3, :3], W[:3, 3] = rotvec_to_matrix(p[3:6]), p[:3]
            base = W @ base
        elif e.name == "tool_offset":
            tool[:3, 3] = tool[:3, 3] + p
        else:
            rest.append({"spec": e.spec(), "parameters": {n: {"value": float(v), "unit": u} for n, v, u in
                                                          zip(e.param_names(), p.tolist(), e.param_units())}})
    cal = dataclasses.replace(r, table=r.table + geo, base=base, tool=tool)
    return cal, rest


def table_csv(r) -> str:
    lines = ["joint,type,theta_offset_deg,d_mm,a_mm,alpha_deg,beta_deg,lower,upper"]
    for i in range(r.n):
        off, d, a, al, be = r.table[i].tolist()
        p = bool(r.prismatic[i])
        lo, hi = r.limits[i].tolist() if p else [math.degrees(v) for v in r.limits[i].tolist()]
        lines.append(",".join([str(i + 1), "prismatic" if p else "revolute",
                               *(repr(v) for v in (math.degrees(off), d, a, math.degrees(al), math.degrees(be))),
                               "%.12g" % lo, "%.12g" % hi]))
    return "\n".join(lines) + "\n"


def refit_export(model, theta, args, identified=None):
    """(robot, []) of the geometry alone refitted on --data, after one line with the RMS of
    the exported robot alone, the full model and the model's geometry without its effects."""
    from torchcal.calibration.geometry_only import refit_geometry
    from torchcal.calibration.mismatch import check_measurements, enforce
    from torchcal.cli._args import read_data

    m = read_data(args.data, model.robot, args)
    enforce(check_measurements(model, theta.to(m.xyz), m, getattr(model, "training_rms_mm", None)))
    r = refit_geometry(model, theta, m, identified=identified)
    print(f"geometry alone refitted on {len(m)} rows of {args.data} (without {', '.join(r.dropped)}): exported robot "
          f"alone rms {r.refit_rms_mm:.4f} mm; full model {r.full_rms_mm:.4f} mm; the model's geometry without its "
          f"effects {r.naive_rms_mm:.4f} mm (solver {r.fit.status})")
    cal, _ = calibrated_robot(r.fit.model, r.fit.theta)
    return cal, []


def run(args) -> int:
    from torchcal.io.interval_model import load_interval_model as load_model
    from torchcal.errors import InputError
    from torchcal.io.files import atomic_write
    from torchcal.robots.robot_file import write_robot_file
    from torchcal.robots.urdf import minimal_urdf

    outs = [("--robot-file", args.robot_file), ("--urdf", args.urdf), ("--table", args.table)]
    if not any(p for _, p in outs):
        raise InputError("export: give at least one of --robot-file, --urdf, --table")
    check_outputs(outs, args.force, inputs=[args.model, args.data])
    im = load_model(args.model)
    if getattr(im.model, "residual_model", None) is not None:
        print(f"{args.model}: its non-physical residual stage is dropped (a URDF, robot file or table holds only "
              f"the physical model)")
    cal, rest = calibrated_robot(im.model, im.theta[0])
    if rest and args.data:
        cal, rest = refit_export(im.model, im.theta[0], args, identified=im.free[0])
    elif rest:
        sys.stderr.write("torchcal export: warning: effects not held by an MD-H table or a URDF (listed under "
                         f"\"effects\" in the robot file): {', '.join(e['spec'] for e in rest)}; the exported "
                         "geometry alone is worse than the full model (its deviations were fitted together with "
                         "those effects) and by how much cannot be told without data: pass --data DATA.csv to "
                         "refit the geometry alone and see both figures\n")
    elif args.data:
        print(f"{args.model}: every effect is held by the exported robot; --data not needed")
    import dataclasses
    from pathlib import Path

    from torchcal.robots.urdf import calibrated_urdf

    urdf_text, urdf_info = None, None
    if args.urdf:
        if cal.urdf is not None:
            urdf_text, tip = calibrated_urdf(im.model.robot, cal)
            urdf_info = {"path": str(Path(args.urdf).resolve()), "base_link": cal.urdf["base_link"], "tip_link": tip}
            print(f"{args.urdf}: the links of {cal.urdf['path']} with calibrated joint origins; TCP link {tip}")
        else:
            urdf_text = minimal_urdf(cal)
            urdf_info = {"path": str(Path(args.urdf).resolve()), "base_link": "base_link", "tip_link": "tcp"}
    # the calibrated robot file points at the calibrated URDF, never at the nominal one
    cal = dataclasses.replace(cal, urdf=urdf_info)
    if args.robot_file:
        write_robot_file(args.robot_file, cal, effects=rest, force=args.force, inputs=[args.model])
    if args.urdf:
        atomic_write(args.urdf, urdf_text, force=args.force, inputs=[args.model])
    if args.table:
        atomic_write(args.table, table_csv(cal), force=args.force, inputs=[args.model])
    print(f"exported {cal.name} ({cal.n} joints) from {args.model}: "
          + ", ".join(f"{o} {p}" for o, p in outs if p))
    return 0
