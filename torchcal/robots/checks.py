"""A robot's own numbers in another unit, and two robots that are not the same.

Robot files (`check_robot_angles`): every revolute limit within +-2 pi "degrees", or a
twist or offset of pi / 2 or pi "degrees" in a file with no angle beyond 2 pi "degrees",
are radians written where degrees belong. (`check_robot_lengths`): an arm whose links (sum
over joints of ``sqrt(d^2 + a^2)``, prismatic strokes included, `link_reach_mm`) reach less
than MIN_REACH_MM = 50 mm is not an industrial arm; its lengths were written in metres. One
that reaches more than MAX_REACH_MM = 100 m was written in micrometres (a URDF import: in
millimetres). A reducer ratio below 1 (`check_gear_ratio`: the motor turning slower than
its joint) was written inverted, joint turns per motor turn: one `RobotUnitWarning`.
Two consecutive joint axes parallel (a twist alpha within PARALLEL_DEG of 0 or 180 deg) with
no Hayati beta on the first (`warn_parallel_axes`): a tilt between the two axes has no
parameter in the table, so no fit can take it out; two revolute joints on one line: their
angles add (a table in Craig's modified D-H convention, `distal_from_proximal`, reads
this way); one `ParallelAxesWarning`.
A workspace floor more than BASE_BELOW_FLOOR_MM above the robot's own base
(`warn_base_below_floor`: the world frame of an exported robot file is the measuring frame)
is named in one `FloorWarning`.

Robots (`check_same_robot`, `robot_differences`): a model applied to another robot than
the one it was fitted for, and a sweep or partition file made for another robot than the
one given (another joint count, joint types, MD-H table, base, tool or joint limits;
`torchcal.io.robot_file.check_record` reads the file's record and names the differences in
its one line). A model with gravity-driven effects given a robot of its geometry mounted
otherwise (`warn_other_gravity`: another gravity direction) is named in one warning.
"""

from __future__ import annotations

import math
import warnings

import torch

from torchcal.errors import InputError

MIN_REACH_MM = 50.0
MIN_STROKE_MM = 1.0  # a prismatic joint travelling less: its limits were written in metres
MAX_REACH_MM = 100_000.0  # 100 m of links and strokes: beyond the longest linear track
MAX_TURN_DEG = 720.0  # a revolute limit beyond two turns either way (a URDF's is refused there)
BASE_BELOW_FLOOR_MM = 100.0  # a base this far below the workspace's floor: the floor is not the robot's
PARALLEL_DEG = 1.0  # axes closer than this are parallel: plain D-H has no parameter for a tilt between them
COAXIAL_MM = 1e-3  # parallel axes closer than this (a_i): one line
MIN_GEAR_RATIO = 1.0  # motor turns per joint turn: a direct drive's 1; less is written inverted


def check_same_robot(model_robot, robot, where: str, what: str = "the given robot") -> None:
    """Refuse (one InputError line naming both) when `robot` is not the robot the model
    was fitted for: another joint count, joint types, nominal table, base or tool, and
    what differs (`robot_differences`: a robot file of the same name with another tool
    reads "the tool differs")."""
    if robot is None or robot.same_geometry(model_robot):
        return
    diff = "; ".join(d for d in robot_differences(model_robot, robot) if " limits " not in d)  # not geometry
    raise InputError(f"{where}: the model is for robot {model_robot.name!r} ({model_robot.n} joints), "
                     f"but {what} is robot {robot.name!r} ({robot.n} joints) with another nominal "
                     f"geometry{f' ({diff})' if diff else ''}; refusing to apply a model to another robot")


def robot_differences(there, here, atol: float = 1e-9) -> list[str]:
    """What differs between the robot `there` (the one a file was made for) and `here`
    (the one given): joint count, joint types, MD-H table, base, tool or joint limits,
    each as a short phrase ("joint 2 limits -185..185 deg in the file, -170..170 deg given");
    [] when they agree up to `atol` (mm, rad: a robot read back from a file). Names,
    payload, gravity and the clearance model are not compared."""
    if there.n != here.n:
        return [f"{there.n} joints in the file, {here.n} given"]
    a, b = there.to("cpu", torch.float64), here.to("cpu", torch.float64)
    kinds = lambda r, j: "prismatic" if bool(r.prismatic[j]) else "revolute"  # noqa: E731
    types = [j for j in range(a.n) if bool(a.prismatic[j]) != bool(b.prismatic[j])]
    if types:
        j = types[0]
        return [f"joint {j + 1} {kinds(a, j)} in the file, {kinds(b, j)} given"]
    out = []
    rows = [j for j in range(a.n) if not torch.allclose(a.table[j], b.table[j], rtol=0, atol=atol)]
    if rows:
        out.append(f"the MD-H table differs at joint(s) {', '.join(str(j + 1) for j in rows)}")
    out += [f"the {t} differs" for t in ("base", "tool")
            if not torch.allclose(getattr(a, t), getattr(b, t), rtol=0, atol=atol)]
    lim = [j for j in range(a.n) if not torch.allclose(a.limits[j], b.limits[j], rtol=0, atol=atol)]
    if lim:
        j, unit = lim[0], a.joint_units()[lim[0]]
        user = lambda r: [v if unit == "mm" else math.degrees(v) for v in r.limits[j].tolist()]  # noqa: E731
        (lo, hi), (lo2, hi2) = user(a), user(b)
        more = f" (and {len(lim) - 1} more joint(s))" if len(lim) > 1 else ""
        out.append(f"joint {j + 1} limits {lo:g}..{hi:g} {unit} in the file, {lo2:g}..{hi2:g} {unit} given{more}")
    return out


#: effects whose deflection follows the direction of gravity in the base frame (the robot file's "gravity")
GRAVITY_EFFECTS = ("joint_compliance", "link_bending", "axis_tilt", "base_compliance", "joint_clearance")


class RobotGravityWarning(UserWarning):
    """The robot given with a model has another gravity direction (mounting) than the one
    the model's gravity-driven effects were fitted with."""


def warn_other_gravity(fitted, robot, where: str, stacklevel: int = 1) -> bool:
    """One `RobotGravityWarning` when `robot` (a `Robot`, checked to have the geometry of the
    fitted model `fitted`, a `FitResult`: `check_same_robot`) has another gravity direction
    than the model's nominal robot and the model has effects that read it (GRAVITY_EFFECTS,
    by name): the model keeps the gravity it was fitted with (its deflections are those of
    the arm as it was mounted then). Returns whether it warned."""
    there = fitted.model.robot
    g0, g1 = there.gravity.detach().to("cpu", torch.float64), robot.gravity.detach().to("cpu", torch.float64)
    reads = [e.spec() for e in fitted.model.effects if e.name in GRAVITY_EFFECTS]
    if not reads or torch.allclose(g0, g1, rtol=0, atol=1e-6):
        return False
    angle = math.degrees(math.acos(max(-1.0, min(1.0, float(g0 @ g1 / (g0.norm() * g1.norm()))))))
    warnings.warn(f"{where}: the robot given has gravity [{', '.join(f'{v:g}' for v in g1.tolist())}] in its base "
                  f"frame, the model's robot [{', '.join(f'{v:g}' for v in g0.tolist())}] ({angle:.3g} deg apart): "
                  f"the model's {', '.join(reads)} deflect the arm as it was mounted when fitted, and keep doing so; "
                  "an arm mounted otherwise needs a fit of its own", RobotGravityWarning, stacklevel=stacklevel + 1)
    return True


def link_reach_mm(table: torch.Tensor, prismatic: torch.Tensor, limits: torch.Tensor) -> float:
    """Sum over joints of sqrt(d^2 + a^2) plus each prismatic joint's largest |limit|, mm;
    table (n, 5) [theta, d, a, alpha, beta], limits (n, 2)."""
    t = table.detach().to("cpu", torch.float64)
    reach = float(torch.sqrt(t[:, 1] ** 2 + t[:, 2] ** 2).sum())
    pris = prismatic.detach().cpu().bool()
    if pris.any():
        reach += float(limits.detach().to("cpu", torch.float64)[pris].abs().max(-1).values.sum())
    return reach


class RobotUnitWarning(UserWarning):
    """A robot file's value looks written in another unit (one joint's limits in radians)."""


def check_robot_lengths(table, prismatic, limits, where: str = "robot file", urdf: bool = False) -> None:
    """InputError when the links reach less than MIN_REACH_MM (lengths in metres) or more
    than MAX_REACH_MM (a URDF written in mm, read as metres; a robot file in micrometres);
    a robot file's prismatic joint travelling less than MIN_STROKE_MM among links that
    reach farther: one `RobotUnitWarning` (its limits in metres).
    urdf: the lengths were read from a URDF (metres there), named as such."""
    reach = link_reach_mm(table, prismatic, limits)
    if reach > MAX_REACH_MM:
        raise InputError(f"{where}: the links reach {reach / 1000:.4g} m in all (sum of sqrt(d^2 + a^2), prismatic "
                         f"strokes included), more than any robot's {MAX_REACH_MM / 1000:g} m: the lengths look like "
                         + ("millimetres; URDF takes metres (joint origins, prismatic limits)" if urdf else
                            "micrometres; robot files take millimetres (d_mm, a_mm, base, tool, prismatic limits)"))
    pris = prismatic.detach().cpu().bool()
    stroke = (limits[:, 1] - limits[:, 0]).detach().to("cpu", torch.float64)
    short = [j for j in range(len(pris)) if bool(pris[j]) and float(stroke[j]) < MIN_STROKE_MM]
    if short and reach >= MIN_REACH_MM and not urdf:  # a slide in metres among links in mm
        j = short[0]
        lo, hi = limits[j].tolist()
        warnings.warn(f"{where}: joints[{j + 1}] (prismatic) travels only {hi - lo:.4g} mm ({lo:g}..{hi:g}): "
                      f"the limits look like metres ({1000 * lo:g}..{1000 * hi:g} mm if they are); robot files "
                      "take millimetres (lower, upper)", RobotUnitWarning, stacklevel=4)
    if reach < MIN_REACH_MM:
        raise InputError(f"{where}: the links reach only {reach:.4g} mm in all (sum of sqrt(d_mm^2 + a_mm^2)), less "
                         f"than any industrial arm's {MIN_REACH_MM:g} mm: the lengths look like metres; robot files "
                         "take millimetres (d_mm, a_mm, base, tool, prismatic limits)")


def check_robot_angles(table, prismatic, limits, where: str = "robot file") -> None:
    """InputError for angles a robot file holds in radians where it takes degrees:
    table (n, 5) [theta, d, a, alpha, beta] rad and limits (n, 2) (rad for a revolute
    joint) as read from the file's degrees (module docstring). Every revolute joint's
    limits within +-2 pi "degrees" (an arm whose joints all turn less than 6.3 deg); or a
    twist alpha or offset theta within 1e-3 of pi / 2 or pi "degrees" while none lies
    beyond 2 pi "degrees" (90 deg written as 1.5708). Some revolute joints' limits within
    +-2 pi "degrees" and the others' beyond: one `RobotUnitWarning` naming the first; so
    does a revolute limit beyond MAX_TURN_DEG (two turns: tenths of a degree or encoder
    counts, which plan and simulate would draw poses from)."""
    t = torch.rad2deg(table.detach().to("cpu", torch.float64))
    rev = ~prismatic.detach().cpu().bool()
    lim = torch.rad2deg(limits.detach().to("cpu", torch.float64))[rev]
    if lim.numel() and float(lim.abs().max()) <= 2 * math.pi + 0.01:
        raise InputError(f"{where}: every revolute joint's limits lie within +-{float(lim.abs().max()):.4g} deg: "
                         "they look like radians; robot files take degrees (lower, upper)")
    turn = lim.abs().amax(-1)  # (revolute joints,) the farthest each turns, "deg"
    narrow = (turn <= 2 * math.pi + 0.01).nonzero().flatten().tolist()
    if narrow:  # some joints in radians, the others in degrees (a URDF's values copied in)
        j = int(rev.nonzero().flatten()[narrow[0]])
        lo, hi = lim[narrow[0]].tolist()
        more = f" (and {len(narrow) - 1} more joint(s))" if len(narrow) > 1 else ""
        warnings.warn(f"{where}: joints[{j + 1}] limits {lo:.6g}..{hi:.6g} deg{more} look like radians "
                      f"({math.degrees(lo):.4g}..{math.degrees(hi):.4g} deg if they are), while the other joints "
                      f"turn up to {float(turn.max()):.4g} deg; robot files take degrees (lower, upper)",
                      RobotUnitWarning, stacklevel=4)
    ang = t[:, [0, 3]]  # theta offsets and twists, deg
    if float(ang.abs().max()) <= 2 * math.pi + 0.01:
        near = [(j, k, float(ang[j, c])) for j in range(ang.shape[0]) for c, k in enumerate(("theta_offset_deg",
                                                                                            "alpha_deg"))
                if min(abs(abs(float(ang[j, c])) - math.pi / 2), abs(abs(float(ang[j, c])) - math.pi)) < 1e-3]
        if near:
            j, k, v = near[0]
            raise InputError(f"{where}: joints[{j + 1}].{k} = {v:.6g}: pi/2 or pi written in radians (and no angle "
                             "of the file beyond 6.3 deg); robot files take degrees (e.g. 90, not 1.5708)")
    wide = (turn > MAX_TURN_DEG).nonzero().flatten().tolist()
    if wide:  # limits in tenths or thousandths of a degree, or encoder counts
        j = int(rev.nonzero().flatten()[wide[0]])
        lo, hi = lim[wide[0]].tolist()
        more = f" (and {len(wide) - 1} more joint(s))" if len(wide) > 1 else ""
        warnings.warn(f"{where}: joints[{j + 1}] limits {lo:.6g}..{hi:.6g} deg{more} turn "
                      f"{float(turn[wide[0]]) / 360:.4g} turns, beyond the {MAX_TURN_DEG / 360:g} turns of a robot "
                      "joint: another unit (tenths or thousandths of a degree, encoder counts)? Robot files take "
                      "degrees (lower, upper); plan, simulate and compensate draw joint values up to them",
                      RobotUnitWarning, stacklevel=4)


def check_gear_ratio(ratio, where: str = "robot file") -> None:
    """One `RobotUnitWarning` when a reducer ratio of `ratio` (the robot file's "gear_ratio":
    n entries, motor turns per joint turn, > 0, or None where unknown) lies below
    MIN_GEAR_RATIO: a robot's reducers run from 1 (direct drive) to a few hundred, and
    0.0099 is 1 / 101 written as joint turns per motor turn. `gear_transmission` would read
    its harmonics at 1 / r^2 of the true motor-side frequency: nearly constant over the
    joint's range, fitted as an offset and a scale (ur5e, ratio 101 written 1 / 101: fit rms
    0.31 mm against 0.034 mm, in silence before this check)."""
    low = [(j, float(r)) for j, r in enumerate(ratio or (), start=1) if r is not None and float(r) < MIN_GEAR_RATIO]
    if low:
        j, r = low[0]
        more = f" (and {len(low) - 1} more joint(s))" if len(low) > 1 else ""
        warnings.warn(f"{where}: gear_ratio[{j}] = {r:.4g}{more} is below {MIN_GEAR_RATIO:g}, the motor turning "
                      f"slower than the joint: it looks inverted, joint turns per motor turn ({1 / r:.4g} if so); "
                      "gear_ratio takes motor turns per joint turn (e.g. 101)", RobotUnitWarning, stacklevel=5)


class ParallelAxesWarning(UserWarning):
    """A robot file's consecutive parallel joint axes without a Hayati beta on the first."""


def warn_parallel_axes(robot, where: str = "robot file", stacklevel: int = 1) -> bool:
    """One `ParallelAxesWarning` when joint i's twist alpha (row i of `robot.table`) lies
    within PARALLEL_DEG of 0 or 180 deg, so that joint i+1's axis is parallel to joint i's
    (the last joint has no next axis), and either
    - both joints are revolute and a_i is 0 (below COAXIAL_MM): the two turn about one
      line, their angles add and no data tell them apart. A table in Craig's modified D-H
      convention (row i holding a and alpha of the link before joint i; its first row's are
      0) reads this way: a Franka Panda's typed in, joints 1 and 2; or
    - joint i declares no beta: the row rotates only about z and x, so a tilt of the next
      axis about y (a few thousandths of a degree on a real arm) cannot be fitted and stays
      in the residual, where discover finds no effect to name (ur5e written without its
      two betas, axes tilted up to 0.02 deg: fit rms 0.074 mm against 0.033 mm with them).
    Returns whether it warned."""
    t = robot.table.detach().to("cpu", torch.float64)
    rev = ~robot.prismatic.detach().cpu().bool()
    parallel = t[:-1, 3].sin().abs() < math.sin(math.radians(PARALLEL_DEG))
    coaxial = (parallel & (t[:-1, 2].abs() < COAXIAL_MM) & rev[:-1] & rev[1:]).nonzero().flatten().tolist()
    bare = (parallel & ~robot.has_beta.detach().cpu().bool()[:-1]).nonzero().flatten().tolist()
    if coaxial:
        j = coaxial[0] + 1
        a = float(t[j - 1, 2]) if abs(float(t[j - 1, 2])) > 1e-9 else 0.0
        craig = ("" if robot.urdf is not None else
                 " A table in Craig's modified D-H convention (row i holding a and alpha of the link before joint i) "
                 "reads this way; torchcal's row i holds the link after joint i, Rz(theta) Tz(d) Tx(a) Rx(alpha): "
                 "move each row's a_mm and alpha_deg up one row (docs/robots.md)")
        warnings.warn(f"{where}: joints[{j}] and joints[{j + 1}] turn about one line (joints[{j}].a_mm {a:.6g}, "
                      f"alpha_deg {math.degrees(float(t[j - 1, 3])):.6g}): their angles add and no data tell them "
                      f"apart.{craig}", ParallelAxesWarning, stacklevel=stacklevel + 1)
        return True
    if not bare:
        return False
    j = bare[0] + 1
    more = f" (so has joints[{'], joints['.join(str(k + 1) for k in bare[1:])}])" if len(bare) > 1 else ""
    warnings.warn(f"{where}: joints[{j}] has no beta_deg while joints[{j + 1}]'s axis is parallel to its own "
                  f"(joints[{j}].alpha_deg {math.degrees(float(t[j - 1, 3])):.6g}){more}: a tilt between the two "
                  f"axes has no parameter to fit and stays in the residual; add \"beta_deg\": 0 to joints[{j}]"
                  f"{' and the others' if more else ''} (the Hayati beta, docs/robots.md)", ParallelAxesWarning,
                  stacklevel=stacklevel + 1)
    return True


def distal_from_proximal(robot):
    """The robot of a table written in Craig's modified (proximal) D-H convention, whose
    row i holds a_(i-1), alpha_(i-1) (the link before joint i: Rx(alpha) Tx(a) Rz(theta)
    Tz(d)), read the way torchcal reads rows (the link after joint i: Rz(theta) Tz(d) Tx(a)
    Rx(alpha), docs/robots.md): each row's a and alpha moved up one row, the last row's 0,
    the first row's Rx(alpha) Tx(a) folded into the base. `robot` (n joints) as read from
    such a file -> the `Robot` it describes (betas as declared)."""
    import dataclasses

    t = robot.table.clone()
    a0, al0 = float(t[0, 2]), float(t[0, 3])
    t[:, 2:4] = torch.cat([t[1:, 2:4], torch.zeros_like(t[:1, 2:4])])
    c, s = math.cos(al0), math.sin(al0)
    first = torch.tensor([[1.0, 0, 0, a0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]], dtype=t.dtype, device=t.device)
    return dataclasses.replace(robot, table=t, base=robot.base @ first)


class FloorWarning(UserWarning):
    """The workspace's floor lies above the robot's own base: its world frame is not the cell's."""


def warn_base_below_floor(robot, floor_z_mm: float, stacklevel: int = 1) -> bool:
    """One `FloorWarning` (True) when the robot's base, the origin of its joint-1 frame at
    z = robot.base[2, 3] mm of its world frame, lies more than BASE_BELOW_FLOOR_MM below
    the workspace floor z = floor_z_mm (`torchcal.robots.workspace.Workspace`): a robot
    standing under its floor. The world frame of a robot file written by `torchcal export`
    is the measuring frame (the tracker's head, e.g. 1226 mm above the UR10 of
    examples/ur10): a floor at its z = 0 kept only the poses whose TCP lay more than 1225
    mm above the base, and `plan` drew its 30 poses from a slab 1225..1263 mm high (the
    robot file it was fitted with: 11..1384 mm) in silence before this check."""
    z = float(robot.base[2, 3])
    if z >= floor_z_mm - BASE_BELOW_FLOOR_MM:
        return False
    warnings.warn(f"workspace: the floor z > {floor_z_mm:g} mm lies {floor_z_mm - z:.0f} mm above the robot's base "
                  f"(its joint-1 frame at z = {z:.0f} mm of the robot file's world frame): only poses whose TCP lies "
                  f"that high above the base are kept; a world frame that is not the cell's (a robot file written "
                  f"by torchcal export has the measuring frame)? Put the floor at or below the base (a floor of "
                  f"{z:.0f} mm: plan's floor option, Workspace(floor_z_mm={z:.0f})) or use the robot file the "
                  "model was fitted with",
                  FloorWarning, stacklevel=stacklevel + 1)
    return True
