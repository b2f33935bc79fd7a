"""`torchcal export MODEL.json [--robot-file OUT.json] [--urdf OUT.urdf] [--table OUT.csv]`:
the calibrated geometry for a controller or a simulator.

- ``--robot-file``: a robot file (docs/robots.md): nominal MD-H table + identified
  deviations, the ``base_frame`` effect folded into ``base``, ``tool_offset`` into ``tool``
  (torchcal's own file: it predicts in the measuring frame, as the model does).
- ``--urdf``: a URDF for a controller or MoveIt: its joint origins carry the calibrated
  geometry, the robot's own base link and tool link (``tool0``) stay where the robot has
  them, and the measuring set-up hangs on them as separate fixed frames: link
  ``tracker`` (the measuring frame, on the base link) and ``reflector`` (the measured
  point, ``reflector_ID`` per point id, on the tool link). A robot imported from a URDF
  (``torchcal robot import``) keeps that file's links, inertias and visuals: its joint
  origins and axes are rewritten (torchcal.io.urdf.calibrated_urdf); otherwise a
  minimal URDF (links base_link, link1..linkN, tool0; `minimal_urdf`).
- ``--table``: CSV ``joint,type,theta_offset_deg,d_mm,a_mm,alpha_deg,beta_deg,lower,upper``:
  the joint rows only. When the calibrated robot has a base or a tool other than the
  identity (a measuring frame, a tool offset, the robot file's own), one line says that
  they are not in the table, with their translations, and that ``--robot-file`` and
  ``--urdf`` carry them.

Effects a URDF or an MD-H table cannot hold (compliance, backlash, gear, thermal...): the
model's MD-H deviations were fitted together with them and absorbed part of them, so its
geometry alone is worse than the best geometry-only robot. With ``--data DATA.csv`` the
geometry alone is refitted on DATA, starting from the model
(torchcal.calibration.geometry_only), that geometry is exported, and one line gives the
RMS on DATA of the exported robot alone, of the full model and of the model's geometry
without its effects. Without ``--data`` the effects are listed in the robot file under
``"effects"`` with their values and one line says that the exported geometry alone is
worse and that by how much cannot be told without data.
A per-zone model (``calibrate --partition``) has one parameter set per zone, which none
of these files can hold: its global calibration is exported (zone 1's for a file of the
older interval-model format, whose global set is zone 1's), and one line says so.

No output replaces an input, ``--force`` included: the model, ``--data``, and what the
model records it came from (its data, the URDF its robot was imported from), and a
``--robot-file`` that holds the model's nominal robot (the robot file it was fitted with). Every
output's folder is tried before the work; one "wrote PATH" line per file written.
"""

from __future__ import annotations

import sys

from torchcal.cli._args import add_force, add_units, check_outputs
from torchcal.errors import InputError


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


def run(args) -> int:
    from torchcal.api import export
    from torchcal.cli._args import units, warnings_to_stderr
    from torchcal.io.measurement_csv import FILE_WARNINGS

    outs = [("--robot-file", args.robot_file), ("--urdf", args.urdf), ("--table", args.table)]
    if not any(p for _, p in outs):
        raise InputError("export: give at least one of --robot-file, --urdf, --table")
    check_outputs(outs, args.force, inputs=[args.model, args.data])
    with warnings_to_stderr(*FILE_WARNINGS):
        res = export(args.model, robot_file=args.robot_file, urdf=args.urdf, table=args.table, data=args.data,
                     force=args.force, **units(args))
    d = res.to_dict()
    if d["zones"] > 1:
        which = ("zone 1's parameters are exported (a file of the older interval-model format stores no global "
                 "calibration)") if d["zone1"] else "its global calibration is exported"
        print(f"{args.model}: a per-zone model ({d['zones']} zones); a robot file, URDF or MD-H table holds one "
              f"parameter set: {which}, not the zones' own parameters (which evaluate and compensate use)")
    if d["residual_stage_dropped"]:
        print(f"{args.model}: its non-physical residual stage is dropped (a URDF, robot file or table holds only "
              f"the physical model)")
    r = d["refit"]
    if r is not None:
        print(f"geometry alone refitted on {r['rows']} rows of {args.data} (without {', '.join(r['dropped'])}): "
              f"exported robot alone rms {r['refit_rms_mm']:.4f} mm; full model {r['full_rms_mm']:.4f} mm; the "
              f"model's geometry without its effects {r['naive_rms_mm']:.4f} mm (solver {r['status']})")
    elif d["effects_not_held"]:
        sys.stderr.write("torchcal export: warning: effects not held by an MD-H table or a URDF (listed under "
                         f"\"effects\" in the robot file): {', '.join(d['effects_not_held'])}; the exported "
                         "geometry alone is worse than the full model (its deviations were fitted together with "
                         "those effects) and by how much cannot be told without data: pass --data DATA.csv to "
                         "refit the geometry alone and see both figures\n")
    elif args.data:
        print(f"{args.model}: every effect is held by the exported robot; --data not needed")
    u = d["urdf"]
    if u is not None:
        kept = f"the links of {u['source']} with calibrated joint origins" if u["source"] else "a minimal URDF"
        frames = (f"; measuring set-up as separate fixed frames: {', '.join(u['frames'])}" if u["frames"] else "")
        print(f"{args.urdf}: {kept}; the robot's own base {u['base_link']} and tool link {u['tip_link']}{frames}")
    if d["reflectors"] and (args.robot_file or args.table):
        ids = ", ".join(map(str, d["reflectors"]))
        print(f"{args.model}: {len(d['reflectors'])} reflectors (points {ids}), one tool offset each: the robot file "
              f"and table keep the nominal tool; the offsets (mm, flange frame, added to the tool's translation) are "
              f"listed under \"effects\" in the robot file" + (" and are frames reflector_ID of the URDF" if args.urdf
                                                                  else ""))
    if args.table:
        note = table_frames_note(res.robot)
        if note:
            print(f"{args.table}: {note}")
    print(f"exported {d['robot']} ({d['joints']} joints) from {args.model}")
    for _, p in outs:
        if p:
            print(f"wrote {p}")
    return 0


def table_frames_note(robot) -> str | None:
    """What an MD-H table of `robot` (the calibrated `Robot`) leaves out: its base (world
    or measuring frame <- joint-1 frame) and tool (flange <- TCP) where not the identity,
    in words with their translations (mm); None when both are the identity."""
    import torch

    parts = []
    for name, T, what in (("base", robot.base, "measuring frame <- joint-1 frame"), ("tool", robot.tool, "flange <- TCP")):
        if not torch.allclose(T, torch.eye(4, dtype=T.dtype), rtol=0, atol=1e-12):
            t = ", ".join(f"{v:.3f}" for v in T[:3, 3].tolist())
            rot = "" if torch.allclose(T[:3, :3], torch.eye(3, dtype=T.dtype), rtol=0, atol=1e-12) else " and a rotation"
            parts.append(f"the {name} ({what}: translation {t} mm{rot})")
    if not parts:
        return None
    return (f"the joint rows only: {' and '.join(parts)} not in it; --robot-file and --urdf carry them "
            f"(the table's chain alone gives the flange in the joint-1 frame)")
