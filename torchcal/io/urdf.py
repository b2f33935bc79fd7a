"""URDF import and export: a serial chain <-> the MD-H `Robot` (docs/robots.md).

Import: pytorch-kinematics (`pk.build_serial_chain_from_urdf`) gives the chain's
structure (which joints lie between the base and tip links, in order). It parses the
origins in float32 (about 1e-4 mm over a metre), so the joint origins (xyz, rpy), axes,
types and limits are re-read here from the URDF's XML in float64.

Conversion (zero configuration, all in the base link's frame, mm):

1. Moving joint i has an axis line (point, unit direction z_i); fixed joints are folded
   into the transforms between moving joints.
2. Frame F_0 (the `base`): z along joint 1's axis, origin on it (closest to the base
   link's origin), x as close as possible to the base link's x.
3. F_i (i = 1..n-1) has z along joint i+1's axis and its origin on that axis:
   - not parallel to joint i's axis (angle >= PARALLEL_DEG): the foot of the common
     normal (plain D-H, beta = 0);
   - (nearly) parallel: where the axis crosses F_(i-1)'s x-y plane, d = 0, with a
     Hayati beta (has_beta).
   Each row [theta, d, a, alpha, beta] is then solved from that origin and direction
   and F_i is rebuilt from the row, so the chain is exact whatever the choice.
4. F_n = F_(n-1) Tz(d_n) with d_n the tip origin's height along joint n's axis; the rest of
   the tip's offset goes into `tool`.
A joint with <mimic> (driven by another joint) is refused: torchcal's joints are
independent, each commanded in its own column. A continuous joint is revolute with limits -180..180 deg; a revolute or prismatic joint
without <limit lower upper> is refused (the URDF standard requires it); a prismatic joint's q (mm)
adds to d.

Export (`minimal_urdf`): one link per MD-H frame, joint i's origin the link transform
A_i at q = 0 and axis z, the tool as a fixed joint to link ``tool0``; `calibrated_urdf`
rewrites the joints of the URDF a robot was imported from. The measuring set-up (the
tracker's frame, the reflector) stays apart from the robot: `add_frames` hangs it on the
base and tip links as fixed frames ``tracker`` and ``reflector``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import torch

from torchcal.errors import InputError
from torchcal.robots.checks import PARALLEL_DEG  # axes closer than this are parallel (Hayati beta)
from torchcal.robots.robot import Robot
from torchcal.rotations import fixed_xyz_to_matrix, matrix_to_fixed_xyz

_F = torch.float64


def _origin(el, where) -> torch.Tensor:
    """(4, 4) mm of an <origin xyz rpy> element (None: identity)."""
    T = torch.eye(4, dtype=_F)
    if el is None:
        return T
    try:
        xyz = [float(v) * 1000.0 for v in (el.get("xyz") or "0 0 0").split()]
        rpy = [float(v) for v in (el.get("rpy") or "0 0 0").split()]
    except ValueError:
        raise InputError(f"{where}: origin: expected numbers in xyz and rpy") from None
    if len(xyz) != 3 or len(rpy) != 3:
        raise InputError(f"{where}: origin: expected 3 values in xyz and rpy")
    T[:3, :3] = fixed_xyz_to_matrix(torch.tensor(rpy, dtype=_F))  # URDF rpy: R = Rz(y) Ry(p) Rx(r)
    T[:3, 3] = torch.tensor(xyz, dtype=_F)
    return T


XACRO_NS = "{http://www.ros.org/wiki/xacro}"


def _root(path):
    """The URDF's XML root; InputError for a missing file, bad XML or a xacro file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: URDF file does not exist")
    xacro = f"{path}: a xacro file (macros, not a URDF): expand the xacro first (xacro {path.name} > robot.urdf)"
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        if path.suffix == ".xacro" or "xacro" in path.read_text(errors="replace"):
            raise InputError(xacro) from None
        raise InputError(f"{path}: not a valid URDF (XML): {exc}") from None
    if path.suffix == ".xacro" or any(el.tag.startswith(XACRO_NS) for el in root.iter()) \
            or any(v.startswith(XACRO_NS) for v in root.attrib):
        raise InputError(xacro)
    return root


def _chain_joint_names(path: Path, base_link: str, tip_link: str) -> list[str]:
    """Joint names from base to tip (fixed ones included), by pytorch-kinematics."""
    import io
    from contextlib import redirect_stderr

    import pytorch_kinematics as pk

    try:  # its parser prints 'Unknown attribute / tag' for every non-kinematic URDF element: silenced
        with redirect_stderr(io.StringIO()):
            chain = pk.build_serial_chain_from_urdf(path.read_bytes(), tip_link, base_link)
    except Exception as exc:  # pk raises ValueError / KeyError / AttributeError
        raise InputError(f"{path}: no serial chain from {base_link!r} to {tip_link!r}: {exc}") from None
    frames = chain._serial_frames
    if frames[0].name != base_link or frames[-1].name != tip_link:
        raise InputError(f"{path}: no serial chain from {base_link!r} to {tip_link!r}")
    return [f.joint.name for f in frames[1:]]


def read_chain(path, base_link: str, tip_link: str) -> list[dict]:
    """The joints from `base_link` to `tip_link`: [{"name", "type", "origin" (4, 4) mm,
    "axis" (3,), "lower", "upper" (rad / mm or None)}], values read in float64."""
    root = _root(path)
    path = Path(path)
    links = {el.get("name") for el in root.findall("link")}
    for what, link in (("base link", base_link), ("tip link", tip_link)):
        if link not in links:
            raise InputError(f"{path}: {what}: no link {link!r}; links: {', '.join(sorted(links))}")
    by_name = {el.get("name"): el for el in root.findall("joint")}
    parent = {}  # child link -> parent link
    for el in by_name.values():
        c, p = el.find("child"), el.find("parent")
        if c is not None and p is not None:
            parent[c.get("link")] = p.get("link")

    def above(link):  # the links from `link` up to the root
        out = [link]
        while out[-1] in parent and len(out) <= len(parent):
            out.append(parent[out[-1]])
        return out
    if base_link not in above(tip_link):
        swapped = tip_link in above(base_link)
        raise InputError(f"{path}: no serial chain from base link {base_link!r} to tip link {tip_link!r}: "
                         + (f"{tip_link!r} lies above {base_link!r}; swap them (base link {tip_link!r}, tip link {base_link!r})"
                            if swapped else f"{base_link!r} is not on the way from the root to {tip_link!r} "
                            f"({' <- '.join(above(tip_link))})"))
    out = []
    for name in _chain_joint_names(path, base_link, tip_link):
        el = by_name[name]
        where = f"{path}: joint {name!r}"
        jtype = el.get("type")
        if jtype not in ("revolute", "continuous", "prismatic", "fixed"):
            raise InputError(f"{where}: type {jtype!r} is not supported (revolute, continuous, prismatic, fixed)")
        mimic = el.find("mimic")
        if mimic is not None and jtype != "fixed":  # driven by another joint: no command of its own
            parent_link = el.find("parent").get("link")
            raise InputError(f"{where}: mimics joint {mimic.get('joint')!r} (<mimic multiplier="
                             f"{mimic.get('multiplier', '1')} offset={mimic.get('offset', '0')}>): torchcal models "
                             f"independent joints only and would read it as one commanded in a column of its own; "
                             f"end the chain above it (tip link {parent_link!r}) or make it fixed at its pose")
        ax = el.find("axis")
        axis = torch.tensor([float(v) for v in (ax.get("xyz") if ax is not None else "1 0 0").split()], dtype=_F)
        if jtype != "fixed":
            if axis.shape != (3,) or float(axis.norm()) < 1e-12:
                raise InputError(f"{where}: axis: expected a non-zero 3-vector")
            axis = axis / axis.norm()
        lim = el.find("limit")
        lower = upper = None
        if jtype == "continuous":
            lower, upper = -math.pi, math.pi
        elif jtype in ("revolute", "prismatic"):
            if lim is None or lim.get("lower") is None or lim.get("upper") is None:
                raise InputError(f"{where}: a {jtype} joint needs <limit lower upper> (the URDF standard; a "
                                 f"joint that turns without end is type continuous, -180..180 deg)")
            else:
                s = 1000.0 if jtype == "prismatic" else 1.0
                lower, upper = float(lim.get("lower")) * s, float(lim.get("upper")) * s
                _check_limits(where, jtype, lower, upper)
        out.append({"name": name, "type": jtype, "origin": _origin(el.find("origin"), where), "axis": axis,
                    "lower": lower, "upper": upper})
    return out


MAX_URDF_TURN_RAD = 4 * math.pi  # a revolute limit beyond two turns either way: degrees in a URDF


def _check_limits(where: str, jtype: str, lower: float, upper: float) -> None:
    """InputError for a joint's <limit> (rad, mm for a prismatic joint as converted): not
    finite, lower not below upper, or a revolute limit beyond MAX_URDF_TURN_RAD (degrees
    written where URDF takes radians: 180 read as 10313 deg)."""
    unit = "mm" if jtype == "prismatic" else "rad"
    if not (math.isfinite(lower) and math.isfinite(upper)) or not lower < upper:
        raise InputError(f"{where}: <limit lower={lower:g} upper={upper:g}> ({unit}): expected finite limits with "
                         f"lower below upper")
    turn = max(abs(lower), abs(upper))
    if jtype != "prismatic" and turn > MAX_URDF_TURN_RAD:
        raise InputError(f"{where}: <limit lower={lower:g} upper={upper:g}> turns {math.degrees(turn):.6g} deg, "
                         f"beyond two turns: the limits look like degrees; URDF takes radians")


def urdf_fk(joints: list[dict], q: torch.Tensor) -> torch.Tensor:
    """Float64 reference FK of `read_chain` joints: q (N, n) rad / mm -> tip poses (N, 4, 4) mm."""
    N = q.shape[0]
    T = torch.eye(4, dtype=_F).expand(N, 4, 4)
    k = 0
    for j in joints:
        T = T @ j["origin"]
        if j["type"] == "fixed":
            continue
        M = torch.eye(4, dtype=_F).repeat(N, 1, 1)
        if j["type"] == "prismatic":
            M[:, :3, 3] = q[:, k, None] * j["axis"]
        else:
            M[:, :3, :3] = _axis_angle(j["axis"], q[:, k])
        T = T @ M
        k += 1
    return T


def _axis_angle(u, t):
    """Rotation matrices (N, 3, 3) about unit axis u by angles t (N,)."""
    K = torch.tensor([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]], dtype=_F)
    s, c = torch.sin(t)[:, None, None], torch.cos(t)[:, None, None]
    return torch.eye(3, dtype=_F) + s * K + (1 - c) * (K @ K)


def _row_transform(row) -> torch.Tensor:
    from torchcal.kinematics import mdh as K
    from torchcal.kinematics.chain import Chain

    return K.link_transforms(torch.zeros(1, dtype=_F), Chain.revolute(torch.tensor([row], dtype=_F)))[0]


def _solve_row(o, u, use_beta: bool, x_hint=None) -> list[float]:
    """MD-H row [theta, d, a, alpha, beta] whose end frame has origin o and z along u
    (both in the previous frame)."""
    oxy = math.hypot(float(o[0]), float(o[1]))
    if oxy > 1e-9:
        theta = math.atan2(float(o[1]), float(o[0]))
    elif x_hint is not None:
        theta = math.atan2(float(x_hint[1]), float(x_hint[0]))
    else:
        theta = 0.0
    ct, st = math.cos(theta), math.sin(theta)
    a = float(o[0]) * ct + float(o[1]) * st
    ux = ct * float(u[0]) + st * float(u[1])
    uy = -st * float(u[0]) + ct * float(u[1])
    uz = float(u[2])
    beta = math.asin(max(-1.0, min(1.0, ux))) if use_beta else 0.0
    alpha = math.atan2(-uy, uz)
    return [theta, float(o[2]), a, alpha, beta]


MOUNT_TILT_DEG = 1.0  # a base link tilted more than this from its root: the floor's gravity does not hold


class MountWarning(UserWarning):
    """A URDF's base link mounted tilted (a wall or ceiling robot) under the root it hangs from."""


def mount_gravity(path, base_link: str):
    """(root link, gravity (3,) in `base_link`'s frame, tilt deg) of the fixed joints above
    `base_link` up to the root of the URDF (or the first moving joint), the root's z taken
    as up (ROS REP 103: gravity -z); None when `base_link` is the root."""
    root = _root(path)
    up = {el.find("child").get("link"): el for el in root.findall("joint")
          if el.find("child") is not None and el.find("parent") is not None}
    T, link = torch.eye(4, dtype=_F), base_link
    while link in up and up[link].get("type") == "fixed":
        el = up[link]
        T = _origin(el.find("origin"), f"{path}: joint {el.get('name')!r}") @ T
        link = el.find("parent").get("link")
    if link == base_link:
        return None
    g = T[:3, :3].T @ torch.tensor([0.0, 0.0, -1.0], dtype=_F)
    return link, g, math.degrees(math.acos(max(-1.0, min(1.0, -float(g[2])))))


def robot_from_urdf(path, base_link: str, tip_link: str, name: str | None = None) -> Robot:
    """The MD-H `Robot` of the chain `base_link` -> `tip_link` of a URDF (module doc), named
    `name`, else the URDF's ``<robot name>``, else after the file."""
    joints = read_chain(path, base_link, tip_link)
    moving = [j for j in joints if j["type"] != "fixed"]
    if not moving:
        raise InputError(f"{path}: no moving joint between {base_link!r} and {tip_link!r}")
    # zero-configuration world poses of each moving joint frame and of the tip
    T = torch.eye(4, dtype=_F)
    axes = []  # (point, direction) per moving joint, world mm
    for j in joints:
        T = T @ j["origin"]
        if j["type"] != "fixed":
            axes.append((T[:3, 3].clone(), T[:3, :3] @ j["axis"]))
    tip = T
    # F_0
    p, z = axes[0]
    p = p - torch.dot(p, z) * z  # closest point of the axis to the base origin
    x = torch.tensor([1.0, 0, 0], dtype=_F) - z[0] * z
    if float(x.norm()) < 1e-6:
        x = torch.tensor([0, 1.0, 0], dtype=_F) - z[1] * z
    x = x / x.norm()
    F = torch.eye(4, dtype=_F)
    F[:3, 0], F[:3, 1], F[:3, 2], F[:3, 3] = x, torch.linalg.cross(z, x), z, p
    base = F.clone()
    rows, has_beta = [], []
    for i in range(1, len(moving)):
        Fi = torch.linalg.inv(F)
        pl = Fi[:3, :3] @ axes[i][0] + Fi[:3, 3]  # next axis in F's coordinates
        u = Fi[:3, :3] @ axes[i][1]
        sin_ang = float(torch.linalg.cross(torch.tensor([0, 0, 1.0], dtype=_F), u).norm())
        parallel = sin_ang < math.sin(math.radians(PARALLEL_DEG))
        if parallel:  # where the axis crosses z = 0 (u_z is about +-1)
            o = pl - pl[2] / u[2] * u
            row = _solve_row(o, u, True)
        else:  # common normal between the z axis and the line (pl, u)
            ez = torch.tensor([0, 0, 1.0], dtype=_F)
            n = torch.linalg.cross(ez, u)
            n = n / n.norm()
            # solve s ez + a n = pl + t u for the feet of the common normal
            A = torch.stack([ez, n, -u], dim=1)
            s, a_, t = torch.linalg.solve(A, pl).tolist()
            o = pl + t * u
            row = _solve_row(o, u, False, x_hint=n)
        rows.append(row)
        has_beta.append(parallel)
        F = F @ _row_transform(row)
    # last frame: F_(n-1) Tz(d_n), d_n the tip's height along the last axis
    Fi = torch.linalg.inv(F)
    d_n = float((Fi @ tip)[2, 3])
    rows.append([0.0, d_n, 0.0, 0.0, 0.0])
    has_beta.append(False)
    F = F @ _row_transform(rows[-1])
    tool = torch.linalg.inv(F) @ tip
    pris = [j["type"] == "prismatic" for j in moving]
    # q = 0 of a prismatic joint: the URDF's zero; theta/d offsets come from the rows
    limits = [[j["lower"], j["upper"]] for j in moving]
    from torchcal.robots.checks import check_robot_lengths

    check_robot_lengths(torch.tensor(rows, dtype=_F), torch.tensor(pris), torch.tensor(limits, dtype=_F), str(path),
                        urdf=True)  # a URDF written in millimetres
    mount = mount_gravity(path, base_link)
    if mount is not None and mount[2] > MOUNT_TILT_DEG:  # a wall or ceiling robot imported from its own base
        link, g, tilt = mount
        import warnings
        vec = ", ".join(f"{round(v, 6) + 0.0:.4g}" for v in g.tolist())
        warnings.warn(f"{path}: base link {base_link!r} is mounted {tilt:.4g} deg from the vertical of its root "
                      f"{link!r} (fixed joints): the robot file gets gravity [0, 0, -1] in {base_link!r}'s frame "
                      f"(a floor robot), the URDF says [{vec}]; set \"gravity\": [{vec}] in the robot file or "
                      f"import from {link!r}", MountWarning, stacklevel=2)
    return Robot(name or _root(path).get("name") or Path(path).stem, torch.tensor(rows, dtype=_F), torch.tensor(has_beta),
                 torch.tensor(limits, dtype=_F), base, tool, 0.0,
                 torch.tensor([0.0, 0.0, -1.0], dtype=_F), torch.tensor(pris),
                 {"path": str(Path(path).resolve()), "base_link": base_link, "tip_link": tip_link})


def _origin_xml(T: torch.Tensor) -> str:
    xyz = " ".join(repr(v / 1000.0) for v in T[:3, 3].tolist())
    rpy = " ".join(repr(v) for v in matrix_to_fixed_xyz(T[:3, :3]).tolist())
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def minimal_urdf(robot: Robot, params=None) -> str:
    """URDF text of `robot` with MD-H deviations `params` (n, 5) folded in: links
    ``base_link``, ``link1..linkN``, ``tool0``; joint i's origin is A_i at q = 0 (metres,
    radians), its axis z; the tool a fixed joint to ``tool0``; limits in rad / m."""
    r = robot.to("cpu", _F)
    table = r.table if params is None else r.table + torch.as_tensor(params, dtype=_F)
    lines = ['<?xml version="1.0"?>', f'<robot name="{r.name}">', '  <link name="base_link"/>']
    prev, T = "base_link", r.base
    for i in range(r.n):
        p = bool(r.prismatic[i])
        lo, hi = r.limits[i].tolist()
        if p:
            lo, hi = lo / 1000.0, hi / 1000.0
        lines += [f'  <link name="link{i + 1}"/>',
                  f'  <joint name="joint{i + 1}" type="{"prismatic" if p else "revolute"}">',
                  f'    <parent link="{prev}"/>', f'    <child link="link{i + 1}"/>',
                  f'    {_origin_xml(T)}', '    <axis xyz="0 0 1"/>',
                  f'    <limit lower="{lo!r}" upper="{hi!r}" effort="0" velocity="0"/>', '  </joint>']
        prev, T = f"link{i + 1}", _row_transform(table[i].tolist())
    lines += ['  <link name="tool0"/>', '  <joint name="tool" type="fixed">', f'    <parent link="{prev}"/>',
              '    <child link="tool0"/>', f'    {_origin_xml(T @ r.tool)}', '  </joint>', '</robot>']
    return "\n".join(lines) + "\n"


def add_frames(text: str, base_link: str, tip_link: str, tracker=None, reflectors=()) -> str:
    """URDF text with the measuring set-up as separate fixed frames, the robot's own links
    untouched: link ``tracker`` (the measuring frame; `tracker` (4, 4) mm, measuring frame
    <- robot base frame, so its origin in `base_link` is the inverse) on `base_link`, and
    one link per reflector ((name, (3,) mm in `tip_link`'s frame)) on `tip_link`. A name
    the URDF already has gets the prefix ``torchcal_``."""
    root = ET.fromstring(text)
    names = {el.get("name") for el in root.findall("link")}
    frames = ([] if tracker is None else [("tracker", base_link, torch.linalg.inv(tracker.to(_F)))]) + \
        [(n, tip_link, _translation(xyz)) for n, xyz in reflectors]
    for name, parent, T in frames:
        name = f"torchcal_{name}" if name in names else name
        ET.SubElement(root, "link", name=name)
        jt = ET.SubElement(root, "joint", name=f"{name}_joint", type="fixed")
        ET.SubElement(jt, "parent", link=parent)
        ET.SubElement(jt, "child", link=name)
        _set_origin(jt, T)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def _translation(xyz) -> torch.Tensor:
    T = torch.eye(4, dtype=_F)
    T[:3, 3] = torch.as_tensor(xyz, dtype=_F)
    return T


def calibrated_urdf(nominal: Robot, cal: Robot) -> tuple[str, str]:
    """The URDF `nominal` was imported from, with the calibrated geometry of `cal` (same
    joints; deviations, base and tool folded in) written into its joint origins and axes.

    Links, inertias, visuals and every other element are kept; the XML is re-serialised
    (comments are dropped). Each moving joint's frame follows its link's calibrated MD-H
    frame, moved onto the calibrated joint axis; fixed joints keep their origins except
    the last one before the tip, which takes the calibrated tool. When the tip link hangs
    directly on the last moving joint, a fixed joint and link ``<tip>_calibrated`` are
    appended. Returns (URDF text, tip link of the calibrated TCP).
    """
    info = nominal.urdf
    path = Path(info["path"])
    if not path.is_file():
        raise InputError(f"{path}: the robot's URDF file no longer exists; a calibrated URDF needs it "
                         f"(or re-import the robot)")
    tree = ET.parse(path)
    root = tree.getroot()
    by_name = {el.get("name"): el for el in root.findall("joint")}
    joints = read_chain(path, info["base_link"], info["tip_link"])
    n = nominal.n
    zero = torch.zeros(n, dtype=_F)
    Fn, Fc = nominal.to("cpu", _F).frames(zero), cal.to("cpu", _F).frames(zero)  # (n + 2, 4, 4)
    P_nom = torch.eye(4, dtype=_F)  # nominal pose of the current parent link
    P_cal = torch.eye(4, dtype=_F)
    k = 0
    last_fixed = None
    for j in joints:
        el = by_name[j["name"]]
        J = P_nom @ j["origin"]
        if j["type"] == "fixed":
            P_nom, P_cal, last_fixed = J, P_cal @ j["origin"], (el, P_cal)
            continue
        k += 1
        Jc = Fc[k] @ torch.linalg.inv(Fn[k]) @ J  # the link's calibrated frame
        axis_p, axis_z = Fc[k - 1][:3, 3], Fc[k - 1][:3, 2]
        if j["type"] != "prismatic":  # origin onto the calibrated axis line
            o = Jc[:3, 3]
            Jc[:3, 3] = axis_p + torch.dot(o - axis_p, axis_z) * axis_z
        _set_origin(el, torch.linalg.inv(P_cal) @ Jc)
        ax = el.find("axis")
        if ax is None:
            ax = ET.SubElement(el, "axis")
        ax.set("xyz", " ".join(repr(v) for v in (Jc[:3, :3].T @ axis_z).tolist()))
        P_nom, P_cal, last_fixed = J, Jc, None
    tcp = Fc[n + 1]
    tip = info["tip_link"]
    if last_fixed is not None:
        el, parent = last_fixed
        _set_origin(el, torch.linalg.inv(parent) @ tcp)
    elif float((torch.linalg.inv(P_cal) @ tcp - torch.eye(4, dtype=_F)).abs().max()) > 1e-12:
        new = f"{tip}_calibrated"
        ET.SubElement(root, "link", name=new)
        jt = ET.SubElement(root, "joint", name=f"{new}_joint", type="fixed")
        ET.SubElement(jt, "parent", link=tip)
        ET.SubElement(jt, "child", link=new)
        _set_origin(jt, torch.linalg.inv(P_cal) @ tcp)
        tip = new
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n", tip


def _set_origin(el, T: torch.Tensor) -> None:
    o = el.find("origin")
    if o is None:
        o = ET.SubElement(el, "origin")
    o.set("xyz", " ".join(repr(v / 1000.0) for v in T[:3, 3].tolist()))
    o.set("rpy", " ".join(repr(v) for v in matrix_to_fixed_xyz(T[:3, :3]).tolist()))
