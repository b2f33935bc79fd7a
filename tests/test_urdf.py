"""URDF import (pytorch-kinematics for the chain, float64 origins) and URDF export.

References: pytorch-kinematics' own FK of the URDF (float64 chain, float32-parsed origins:
within 1e-3 mm) and a float64 re-implementation of URDF FK from the XML (`urdf_fk`)."""

import math
import re

import pytest
import torch

from torchcal.errors import InputError
from torchcal.io.urdf import minimal_urdf, read_chain, robot_from_urdf, urdf_fk


def _joint(name, jtype, parent, child, xyz, rpy, axis="0 0 1", lim=(-3.0, 3.0)):
    limit = "" if jtype in ("fixed", "continuous") else \
        f'<limit lower="{lim[0]}" upper="{lim[1]}" effort="1" velocity="1"/>'
    return (f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="{axis}"/>{limit}</joint>')


def _urdf(name, joints):
    links = sorted({j[2] for j in joints} | {j[3] for j in joints})
    body = "".join(f'<link name="{l}"><inertial><mass value="1.0"/><inertia ixx="0.1" ixy="0" ixz="0" '
                   f'iyy="0.1" iyz="0" izz="0.1"/></inertial></link>' for l in links)
    return f'<?xml version="1.0"?><robot name="{name}">{body}{"".join(_joint(*j) for j in joints)}</robot>'


# (a) UR-style 6R: joints 2, 3, 4 parallel, a fixed flange + tool0 at the end
UR = [("shoulder_pan", "revolute", "base_link", "shoulder", "0 0 0.1625", "0 0 0.1"),
      ("shoulder_lift", "revolute", "shoulder", "upper_arm", "0 0 0", "1.570796327 0 0"),
      ("elbow", "revolute", "upper_arm", "forearm", "-0.425 0 0", "0 0 0"),
      ("wrist_1", "revolute", "forearm", "wrist1", "-0.3922 0 0.1333", "0 0 0"),
      ("wrist_2", "revolute", "wrist1", "wrist2", "0 -0.0997 0", "1.570796327 0 0"),
      ("wrist_3", "continuous", "wrist2", "wrist3", "0 0.0996 0", "-1.570796327 0 0"),
      ("flange", "fixed", "wrist3", "flange_link", "0 0 0", "0 -1.570796327 -1.570796327"),
      ("tool", "fixed", "flange_link", "tool0", "0.01 0.02 0.15", "0.3 0.2 0.1")]
# (b) 7-axis arm with tilted origins, tip directly on the last joint
ARM7 = [(f"j{k}", "revolute", f"l{k - 1}", f"l{k}", xyz, rpy, ax) for k, (xyz, rpy, ax) in enumerate([
    ("0.01 0.02 0.34", "0.05 -0.02 0.3", "0 0 1"), ("0 0 0", "-1.5708 0.01 0", "0 0 1"),
    ("0 -0.4 0.002", "1.5708 0 0.02", "0 0 1"), ("0.0 0 0", "1.5708 0 0", "0 0 1"),
    ("0 0.39 0", "-1.5708 0 0", "0 0 1"), ("0 0 0", "-1.5708 0 0.1", "0 0 1"),
    ("0.05 0.12 0.03", "1.5708 0.2 0", "0.6 0 0.8")], start=1)]
# (c) prismatic and fixed joints mixed: fixed, revolute, prismatic (tilted axis), fixed, revolute, fixed
PRIS = [("mount", "fixed", "world", "base", "0.2 -0.1 0.05", "0.1 0.2 0.3"),
        ("turn", "revolute", "base", "column", "0 0 0.3", "0 0 0"),
        ("lift", "prismatic", "column", "carriage", "0.1 0 0.2", "0.2 -0.1 0.4", "0 0.6 0.8", (-0.2, 0.5)),
        ("bracket", "fixed", "carriage", "arm", "0.3 0.05 0", "0 0.3 0"),
        ("wrist", "revolute", "arm", "hand", "0.2 0 0", "0 1.5708 0", "1 0 0"),
        ("tcp", "fixed", "hand", "tcp_link", "0 0.03 0.12", "0.5 0 0.2")]
CASES = {"ur": (UR, "base_link", "tool0"), "arm7": (ARM7, "l0", "l7"), "pris": (PRIS, "world", "tcp_link")}


def _write(tmp_path, key):
    joints, base, tip = CASES[key]
    p = tmp_path / f"{key}.urdf"
    p.write_text(_urdf(key, joints))
    return p, base, tip


def _random_q(robot, n, seed):
    g = torch.Generator().manual_seed(seed)
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    return lo + (hi - lo) * torch.rand(n, robot.n, generator=g, dtype=torch.float64)


@pytest.mark.parametrize("key", list(CASES))
def test_import_matches_pytorch_kinematics(tmp_path, key):
    import pytorch_kinematics as pk

    path, base, tip = _write(tmp_path, key)
    robot = robot_from_urdf(path, base, tip)
    assert robot.n == sum(j[1] != "fixed" for j in CASES[key][0])
    q = _random_q(robot, 1000, 0)
    ours = robot.fk_pose(q)
    # float64 reference from the XML: exact to rounding
    ref = urdf_fk(read_chain(path, base, tip), q)
    assert (ours - ref)[:, :3, 3].abs().max() < 1e-9
    assert (ours - ref)[:, :3, :3].abs().max() < 1e-12
    # pytorch-kinematics (origins parsed in float32)
    chain = pk.build_serial_chain_from_urdf(path.read_bytes(), tip, base).to(dtype=torch.float64)
    qm = torch.where(robot.prismatic, q / 1000.0, q)
    m = chain.forward_kinematics(qm).get_matrix()
    assert (ours[:, :3, 3] - 1000.0 * m[:, :3, 3]).norm(dim=-1).max() < 1e-3


def test_parallel_axes_get_hayati_beta(tmp_path):
    path, base, tip = _write(tmp_path, "ur")
    robot = robot_from_urdf(path, base, tip)
    assert robot.has_beta.tolist() == [False, True, True, False, False, False]
    assert robot.prismatic.tolist() == [False] * 6
    # continuous wrist_3: -180..180 deg
    assert torch.allclose(robot.limits[5], torch.tensor([-math.pi, math.pi], dtype=torch.float64))


def test_prismatic_joint_imported(tmp_path):
    path, base, tip = _write(tmp_path, "pris")
    robot = robot_from_urdf(path, base, tip)
    assert robot.prismatic.tolist() == [False, True, False]
    assert robot.limits[1].tolist() == pytest.approx([-200.0, 500.0])  # mm
    # moving the prismatic joint by 10 mm moves the TCP by 10 mm
    q = torch.zeros(2, 3, dtype=torch.float64)
    q[1, 1] = 10.0
    p = robot.fk(q)
    assert float((p[1] - p[0]).norm()) == pytest.approx(10.0, abs=1e-9)


def _deviations(robot, seed: int) -> torch.Tensor:
    """(n, 5) small random MD-H deviations (rad, mm), dbeta only where the table has beta."""
    g = torch.Generator().manual_seed(seed)
    dev = torch.randn(robot.n, 5, generator=g, dtype=torch.float64) * torch.tensor([1e-3, 0.5, 0.5, 1e-3, 1e-3])
    dev[:, 4] *= robot.has_beta
    return dev


@pytest.mark.parametrize("key", list(CASES))
def test_minimal_export_reimports_to_calibrated_fk(tmp_path, key):
    path, base, tip = _write(tmp_path, key)
    robot = robot_from_urdf(path, base, tip)
    dev = _deviations(robot, 1)
    out = tmp_path / "cal.urdf"
    out.write_text(minimal_urdf(robot, dev))
    back = robot_from_urdf(out, "base_link", "tool0")
    q = _random_q(robot, 1000, 2)
    err = (back.fk_pose(q)[:, :3, 3] - robot.fk_pose(q, dev)[:, :3, 3]).norm(dim=-1).max()
    assert err < 1e-3


def test_bad_links_one_line(tmp_path):
    path, base, tip = _write(tmp_path, "ur")
    with pytest.raises(InputError, match="tip link: no link 'nosuch'"):
        robot_from_urdf(path, base, "nosuch")


@pytest.mark.parametrize("key", list(CASES))
def test_calibrated_urdf_keeps_links_and_carries_calibration(tmp_path, key):
    import dataclasses

    from torchcal.io.urdf import calibrated_urdf

    path, base, tip = _write(tmp_path, key)
    robot = robot_from_urdf(path, base, tip)
    dev = _deviations(robot, 4)
    tool = robot.tool.clone()
    tool[:3, 3] += torch.tensor([0.3, -0.2, 0.4], dtype=torch.float64)
    cal = dataclasses.replace(robot, table=robot.table + dev, tool=tool)
    text, new_tip = calibrated_urdf(robot, cal)
    out = tmp_path / "cal.urdf"
    out.write_text(text)
    assert text.count("<inertial>") == path.read_text().count("<inertial>")
    back = robot_from_urdf(out, base, new_tip)
    q = _random_q(robot, 1000, 5)
    assert (back.fk(q) - cal.fk(q)).norm(dim=-1).max() < 1e-3


def test_robot_import_messages_name_the_cause(tmp_path, capsys):
    from torchcal.cli import main

    path, base, tip = _write(tmp_path, "ur")
    text = path.read_text()
    (tmp_path / "arm.urdf").write_text(text.replace('<robot name="ur">', '<robot name="ur10e_cell">'))
    assert main(["robot", "import", str(tmp_path / "arm.urdf"), "--base", base, "--tip", tip,
                 "--out", str(tmp_path / "arm.json")]) == 0
    assert "robot ur10e_cell:" in capsys.readouterr().out  # the URDF's own name, not the file's
    # a xacro file: its links sit in macros
    (tmp_path / "arm.urdf.xacro").write_text(
        '<?xml version="1.0"?><robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="arm">'
        '<xacro:macro name="arm" params="prefix"><link name="${prefix}base_link"/></xacro:macro>'
        '<xacro:arm prefix=""/></robot>')
    for urdf, b, t, expect in ((tmp_path / "arm.urdf.xacro", "base_link", "tool0", "expand the xacro first"),
                               (tmp_path / "arm.urdf", tip, base, f"swap them (base link {base!r}, tip link {tip!r})")):
        capsys.readouterr()
        assert main(["robot", "import", str(urdf), "--base", b, "--tip", t,
                     "--out", str(tmp_path / "x.json")]) == 2
        err = capsys.readouterr().err
        assert expect in err and len(err.splitlines()) == 1 and "KeyError" not in err
        assert not (tmp_path / "x.json").exists()
    side = tmp_path / "side.urdf"  # a camera on the shoulder: a branch off the chain
    side.write_text(text.replace("</robot>", '<link name="camera"/>' + _joint(
        "cam", "fixed", "shoulder", "camera", "0 0 0.1", "0 0 0") + "</robot>"))
    with pytest.raises(InputError, match="base link 'camera' to tip link 'tool0': 'camera' is not on the way"):
        read_chain(side, "camera", "tool0")


def test_a_revolute_joint_without_limits_is_refused(tmp_path, capsys):
    """The URDF standard requires <limit> on revolute and prismatic joints. A revolute
    joint without one was imported with -180..180 deg (a UR10's +-360 deg cut in half, and
    compensate and plan then held the robot to it); a prismatic one was refused. Now both
    are, in one line naming the joint; a continuous joint still reads as -180..180 deg."""
    from torchcal.cli import main

    joints = [("j1", "revolute", "base", "l1", "0 0 0.1", "0 0 0"), ("j2", "revolute", "l1", "l2", "0 0 0.3", "0 0 0")]
    text = _urdf("arm", joints)
    cut = text.replace('<limit lower="-3.0" upper="3.0" effort="1" velocity="1"/></joint></robot>', "</joint></robot>")
    assert cut.count("<limit") == 1
    (tmp_path / "a.urdf").write_text(cut)
    err = _refused_import(tmp_path, capsys, "a.urdf", "base", "l2")
    assert "'j2'" in err and "<limit" in err
    (tmp_path / "c.urdf").write_text(cut.replace('name="j2" type="revolute"', 'name="j2" type="continuous"'))
    assert main(["robot", "import", str(tmp_path / "c.urdf"), "--base", "base", "--tip", "l2",
                 "--out", str(tmp_path / "c.json")]) == 0
    assert torch.rad2deg(robot_from_urdf(tmp_path / "c.urdf", "base", "l2").limits[1]).tolist() == \
        pytest.approx([-180.0, 180.0])


def _refused_import(tmp_path, capsys, urdf: str, base: str, tip: str) -> str:
    """`torchcal robot import` of tmp_path / urdf refused: exit 2, one line on stderr
    (returned), no robot file written."""
    from torchcal.cli import main

    out = tmp_path / urdf.replace(".urdf", ".json")
    capsys.readouterr()
    assert main(["robot", "import", str(tmp_path / urdf), "--base", base, "--tip", tip, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and not out.exists(), err
    return err


def test_a_mimic_joint_in_the_chain_is_refused(tmp_path, capsys):
    """A joint driven by another (<mimic>, e.g. a parallel-linkage elbow) has no command of
    its own; it was imported as an independent joint, so the robot gained a joint its
    controller never commands and compensate would write a command for it. Now one line
    names it, what it mimics and the tip to end above it; the chain above it imports."""
    joints = [("j1", "revolute", "base", "l1", "0 0 0.1", "0 0 0"),
              ("j2", "revolute", "l1", "l2", "0.3 0 0", "1.5708 0 0"),
              ("j3", "revolute", "l2", "l3", "0.3 0 0", "0 0 0")]
    text = _urdf("arm", joints).replace('name="j3" type="revolute">',
                                        'name="j3" type="revolute"><mimic joint="j2" multiplier="-1"/>')
    (tmp_path / "m.urdf").write_text(text)
    err = _refused_import(tmp_path, capsys, "m.urdf", "base", "l3")
    assert "joint 'j3': mimics joint 'j2'" in err and "(tip link 'l2')" in err
    assert robot_from_urdf(tmp_path / "m.urdf", "base", "l2").n == 2  # the chain above it


def test_a_urdf_in_millimetres_is_refused(tmp_path, capsys):
    """A URDF exported in mm (origins 162.5 where 0.1625 m belongs) was imported as a
    robot of 1.3 km; fit then blamed the data ('positions look like metres; pass
    --length-unit m'). Now the import refuses it in one line naming the unit."""
    joints = [j[:4] + (" ".join(f"{1000 * float(v):g}" for v in j[4].split()),) + j[5:] for j in UR]
    (tmp_path / "mm.urdf").write_text(_urdf("ur", joints))
    err = _refused_import(tmp_path, capsys, "mm.urdf", "base_link", "tool0")
    assert "the links reach 1322 m in all" in err and "look like millimetres; URDF takes metres" in err
    path, base, tip = _write(tmp_path, "ur")  # the same in metres
    assert robot_from_urdf(path, base, tip).n == 6


@pytest.mark.parametrize("limit, words", [
    ('<limit lower="3.0" upper="-3.0"', r"joint 'j2': <limit lower=3 upper=-3> \(rad\): expected finite limits "
                                        r"with lower below upper"),
    ('<limit lower="-180" upper="180"', r"joint 'j2': <limit lower=-180 upper=180> turns 10313.2 deg, beyond two "
                                        r"turns: the limits look like degrees; URDF takes radians")])
def test_urdf_limits_inverted_or_in_degrees_are_refused(tmp_path, capsys, limit, words):
    """A URDF joint with lower > upper was imported into a robot file that no command could
    read; limits in degrees (180 where 3.1416 belongs) gave a robot turning +-10313 deg,
    in silence. Both: one line naming the joint at import, nothing written; UR-style
    +-2 pi limits import."""
    joints = [("j1", "revolute", "base", "l1", "0 0 0.1", "0 0 0"), ("j2", "revolute", "l1", "l2", "0.3 0 0", "0 0 0")]
    text = _urdf("arm", joints)
    last = text.rindex('<limit lower="-3.0" upper="3.0"')
    (tmp_path / "a.urdf").write_text(text[:last] + limit + text[last + len('<limit lower="-3.0" upper="3.0"'):])
    err = _refused_import(tmp_path, capsys, "a.urdf", "base", "l2")
    assert re.search(words, err), err
    (tmp_path / "b.urdf").write_text(text.replace('lower="-3.0" upper="3.0"', 'lower="-6.2832" upper="6.2832"'))
    assert torch.rad2deg(robot_from_urdf(tmp_path / "b.urdf", "base", "l2").limits).abs().max() == \
        pytest.approx(360.0, abs=1e-3)


def test_a_base_link_mounted_on_a_wall_is_named(tmp_path):
    """A UR arm on a wall (a fixed joint world -> base_link pitched 90 deg) imported from
    base_link got gravity [0, 0, -1] in base_link's frame (a floor robot) in silence; now one
    warning names the URDF's gravity [1, 0, 0] there. Imported from world (the mount in its
    base), and the upright arms of these tests, say nothing."""
    import warnings

    from torchcal.io.urdf import MountWarning

    wall = [("mount", "fixed", "world", "base_link", "0 0 1.0", "0 1.5707963268 0")] + UR
    path = tmp_path / "wall.urdf"
    path.write_text(_urdf("wall", wall))
    with pytest.warns(MountWarning, match=r"base link 'base_link' is mounted 90 deg from the vertical of its root "
                                          r"'world'.*the URDF says \[1, 0, 0\]; set \"gravity\": \[1, 0, 0\]"):
        upright = robot_from_urdf(path, "base_link", "tool0")
    with warnings.catch_warnings():
        warnings.simplefilter("error", MountWarning)
        from_world = robot_from_urdf(path, "world", "tool0")
        for key in CASES:
            robot_from_urdf(*_write(tmp_path, key))
    # joint 1's axis: horizontal on the wall (imported from world), vertical as the base_link import reads it
    assert abs(float(from_world.base[:3, 2] @ from_world.gravity)) < 1e-9
    assert abs(float(upright.base[:3, 2] @ upright.gravity)) > 1 - 1e-9
