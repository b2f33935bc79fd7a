"""The calibrated MD-H table of ``torchcal export --table`` (CSV, degrees and mm):

    joint,type,theta_offset_deg,d_mm,a_mm,alpha_deg,beta_deg,lower,upper

one row per joint (1-based), type revolute or prismatic, limits in deg (mm for a
prismatic joint).
"""

from __future__ import annotations

import math

__all__ = ["mdh_table_csv"]


def mdh_table_csv(robot) -> str:
    """The CSV text of `robot`'s MD-H table and joint limits."""
    lines = ["joint,type,theta_offset_deg,d_mm,a_mm,alpha_deg,beta_deg,lower,upper"]
    for i in range(robot.n):
        off, d, a, al, be = robot.table[i].tolist()
        p = bool(robot.prismatic[i])
        lo, hi = robot.limits[i].tolist() if p else [math.degrees(v) for v in robot.limits[i].tolist()]
        lines.append(",".join([str(i + 1), "prismatic" if p else "revolute",
                               *(repr(v) for v in (math.degrees(off), d, a, math.degrees(al), math.degrees(be))),
                               "%.12g" % lo, "%.12g" % hi]))
    return "\n".join(lines) + "\n"
