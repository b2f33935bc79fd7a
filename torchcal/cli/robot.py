"""`torchcal robot show ROBOT` prints a robot's MD-H table (degrees, mm), joint types,
limits, base and tool; `torchcal robot import FILE.urdf --base LINK --tip LINK --out
robot.json` converts a URDF chain to a robot file (torchcal.io.urdf, docs/robots.md)."""

from __future__ import annotations

import math

from torchcal.cli._args import PRESET_NAMES, add_force, check_outputs, load_robot


def add_parser(sub):
    p = sub.add_parser("robot", help="show a robot's MD-H table; import a URDF as a robot file",
                       description=__doc__.splitlines()[0])
    rsub = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    s = rsub.add_parser("show", help="print the MD-H table (deg, mm), types, limits, base and tool")
    s.add_argument("robot", metavar="ROBOT",
                   help=f"a preset ({', '.join(PRESET_NAMES)}) or the path of a robot file (.json)")
    s.set_defaults(func=run_show)
    i = rsub.add_parser("import", help="convert a URDF chain to a robot file (JSON)")
    i.add_argument("urdf", metavar="FILE.urdf", help="URDF file")
    i.add_argument("--base", required=True, metavar="LINK", help="base link of the chain")
    i.add_argument("--tip", required=True, metavar="LINK", help="tip link (the TCP) of the chain")
    i.add_argument("--name", help="robot name (default: the URDF's <robot name>, else the file name)")
    i.add_argument("--out", required=True, help="robot file (.json) to write")
    add_force(i)
    i.set_defaults(func=run_import)
    return p


def format_robot(r) -> str:
    r = r.to("cpu")
    lines = [f"robot {r.name}: {r.n} joints, payload {r.payload_kg:g} kg, gravity {r.gravity.tolist()}",
             f"{'joint':>5} {'type':>9} {'theta_off deg':>14} {'d mm':>12} {'a mm':>12} {'alpha deg':>11} "
             f"{'beta deg':>10} {'lower':>10} {'upper':>10} unit"]
    for i in range(r.n):
        off, d, a, al, be = r.table[i].tolist()
        p = bool(r.prismatic[i])
        lo, hi = r.limits[i].tolist() if p else [math.degrees(v) for v in r.limits[i].tolist()]
        beta = f"{math.degrees(be):>10.4f}" if bool(r.has_beta[i]) else f"{'-':>10}"
        lines.append(f"{i + 1:>5} {'prismatic' if p else 'revolute':>9} {math.degrees(off):>14.4f} {d:>12.4f} "
                     f"{a:>12.4f} {math.degrees(al):>11.4f} {beta} {lo:>10.4f} {hi:>10.4f} {'mm' if p else 'deg'}")
    for key in ("base", "tool"):
        T = getattr(r, key)
        lines.append(f"{key} (mm):")
        lines += ["  " + " ".join(f"{v:>12.6f}" for v in row) for row in T.tolist()]
    if r.urdf:
        lines.append(f"from URDF {r.urdf['path']} ({r.urdf['base_link']} -> {r.urdf['tip_link']})")
    return "\n".join(lines)


def run_show(args) -> int:
    print(format_robot(load_robot(args.robot)))
    return 0


def run_import(args) -> int:
    from torchcal.io.robot_file import write_robot_file
    from torchcal.io.urdf import robot_from_urdf

    check_outputs([("--out", args.out)], args.force, inputs=[args.urdf])
    r = robot_from_urdf(args.urdf, args.base, args.tip, args.name)
    write_robot_file(args.out, r, force=args.force, inputs=[args.urdf])
    print(format_robot(r))
    print(f"wrote {args.out} (origins read in float64 from the URDF's XML; pytorch-kinematics, "
          f"which parses them in float32, gives only the chain's structure)")
    return 0
