"""Units of the measurement file: --length-unit / --angle-unit, the plausibility check that
refuses metres read as mm and radians read as degrees, and the new optional columns."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.calibration.checks.units import check_units, spread_mm
from torchcal.cli import main
from torchcal.errors import InputError
from torchcal.io.measurement_csv import read_measurements, write_measurements
from torchcal.measurements import Measurements
from torchcal.rotations import fixed_xyz_to_matrix, matrix_to_fixed_xyz
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The same simulated session as mm/deg, m/deg and mm/rad files."""
    d = tmp_path_factory.mktemp("units")
    rob = torchcal.robot("ur5e")
    m = VirtualRobot(rob, ["joint_compliance:2,3"], seed=1).measure(random_poses(rob, 40, 3), noise_mm=0.02, seed=4)
    write_measurements(d / "mm.csv", m)
    lines = (d / "mm.csv").read_text().splitlines()
    head, rows = lines[0], [r.split(",") for r in lines[1:]]
    metres = [r[:7] + [repr(float(v) / 1000) for v in r[7:10]] + r[10:] for r in rows]
    rad = [r[:1] + [repr(math.radians(float(v))) for v in r[1:7]] + r[7:] for r in rows]
    (d / "m.csv").write_text("\n".join([head] + [",".join(r) for r in metres]) + "\n")
    (d / "rad.csv").write_text("\n".join([head] + [",".join(r) for r in rad]) + "\n")
    return d


def _fit(d, name, *extra):
    out = d / f"model_{name}_{'_'.join(e.strip('-') for e in extra)}.json"
    code = main(["fit", str(d / f"{name}.csv"), "--robot", "ur5e", "--effects", "base_frame", "tool_offset",
                 "--out", str(out), *extra])
    return code, out


@pytest.mark.parametrize("name, flag, cause", [("rad", "--angle-unit rad", "radians read as degrees")])
def test_wrong_unit_refused_with_cause_and_fix(files, capsys, name, flag, cause):
    """(Metres read as mm: tests/test_cli_api.py, the library's and the CLI's line.)"""
    capsys.readouterr()
    code, out = _fit(files, name)
    err = capsys.readouterr().err
    assert code == 2 and not out.exists()
    assert len(err.strip().splitlines()) == 1
    assert cause in err and flag in err


@pytest.mark.parametrize("flag, cause", [(["--length-unit", "m"], "mm read as metres"),
                                         (["--angle-unit", "rad"], "degrees read as radians")])
def test_flag_on_a_mm_deg_file_refused(files, capsys, flag, cause):
    capsys.readouterr()
    code, out = _fit(files, "mm", *flag)
    err = capsys.readouterr().err
    assert code == 2 and not out.exists() and cause in err and len(err.strip().splitlines()) == 1


def test_right_flags_give_the_same_fit(files):
    code, ref = _fit(files, "mm")
    assert code == 0
    p_ref = {p["name"]: p["value"] for p in json.loads(ref.read_text())["parameters"]}
    for name, flag in (("m", ["--length-unit", "m"]), ("rad", ["--angle-unit", "rad"])):
        code, out = _fit(files, name, *flag)
        assert code == 0
        p = {q["name"]: q["value"] for q in json.loads(out.read_text())["parameters"]}
        assert p.keys() == p_ref.keys()
        for k, v in p_ref.items():  # same data up to the last digits of the text: same fit
            assert p[k] == pytest.approx(v, rel=1e-6, abs=1e-7), k


def test_reader_converts_units(files):
    rob = torchcal.robot("ur5e")
    a = read_measurements(files / "mm.csv", robot=rob)
    b = read_measurements(files / "m.csv", robot=rob, length_unit="m")
    c = read_measurements(files / "rad.csv", robot=rob, angle_unit="rad")
    assert torch.allclose(a.xyz, b.xyz, rtol=1e-12, atol=1e-9)
    assert torch.allclose(a.q, c.q, rtol=1e-12, atol=1e-12)
    with pytest.raises(InputError, match="length unit"):
        read_measurements(files / "mm.csv", length_unit="inch")


def test_spread_is_registration_invariant_and_small_motion_passes():
    rob = torchcal.robot("ur5e")
    q = random_poses(rob, 30, 0)
    p = rob.fk(q)
    R = fixed_xyz_to_matrix(torch.deg2rad(torch.tensor([30.0, -50.0, 100.0], dtype=torch.float64)))
    assert spread_mm(p @ R.T + 2000.0) == pytest.approx(spread_mm(p), rel=1e-12)
    # a genuine data set in degrees that only moves a few degrees is not mistaken for radians
    q_small = torch.deg2rad(torch.tensor([10.0, -80.0, 60.0, -70.0, 80.0, 5.0], dtype=torch.float64)) \
        + torch.deg2rad(torch.rand(20, 6, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 4 - 2)
    m = Measurements(torch.arange(20), q_small, rob.fk(q_small))
    info = check_units(m, rob)
    assert info["ratio"] == pytest.approx(1.0, rel=1e-12)


def test_fixed_xyz_convention():
    """R = Rz(rz) Ry(ry) Rx(rx), checked against scipy's extrinsic 'xyz'."""
    from scipy.spatial.transform import Rotation

    a = torch.tensor([[10.0, -35.0, 120.0], [-170.0, 80.0, -5.0]], dtype=torch.float64)
    R = fixed_xyz_to_matrix(torch.deg2rad(a))
    ref = Rotation.from_euler("xyz", a.numpy(), degrees=True).as_matrix()
    assert torch.allclose(R, torch.as_tensor(ref), atol=1e-14)
    assert torch.allclose(torch.rad2deg(matrix_to_fixed_xyz(R)), a, atol=1e-10)


def test_point_and_orientation_columns_round_trip(tmp_path):
    g = torch.Generator().manual_seed(0)
    N = 6
    m = Measurements(torch.arange(N) // 3, torch.rand(N, 6, generator=g, dtype=torch.float64),
                     torch.randn(N, 3, generator=g, dtype=torch.float64) * 500,
                     point=torch.tensor([1, 2, 3] * 2),
                     rxyz=(torch.rand(N, 3, generator=g, dtype=torch.float64) - 0.5) * 2)
    write_measurements(tmp_path / "a.csv", m)
    text = (tmp_path / "a.csv").read_text()
    assert text.splitlines()[0] == "pose,q1,q2,q3,q4,q5,q6,x,y,z,point,rx,ry,rz"
    b = read_measurements(tmp_path / "a.csv")
    assert torch.equal(b.point, m.point)
    assert torch.allclose(b.rxyz, m.rxyz, rtol=1e-14, atol=1e-15)
    sub = b.subset([1, 4])
    assert sub.point.tolist() == [2, 2] and sub.rxyz.shape == (2, 3)


@pytest.mark.parametrize("header, row, match", [
    ("pose,q1,q2,q3,q4,q5,q6,x,y,z,rx,ry", "0,1,2,3,4,5,6,1,2,3,0,0", "missing rz"),
    ("pose,q1,q2,q3,q4,q5,q6,x,y,z,point", "0,1,2,3,4,5,6,1,2,3,A", "column point: expected an integer point id"),
    ("pose,q1,q2,q3,q4,q5,q6,x,y,z,rx,ry,rz", "0,1,2,3,4,5,6,1,2,3,0,x,0", "column ry: expected a number"),
])
def test_bad_new_columns_one_line_exit_2(tmp_path, capsys, header, row, match):
    f = tmp_path / "bad.csv"
    f.write_text(f"{header}\n{row}\n")
    out = tmp_path / "model.json"
    capsys.readouterr()
    assert main(["fit", str(f), "--robot", "ur5e", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert match in err and len(err.strip().splitlines()) == 1 and not out.exists()


def test_inches_are_named_as_inches(files, capsys):
    """Positions in inches (spread 1/25.4 of the nominal's) are named as inches, not as
    metres with a --length-unit m that would make them 1000 times worse."""
    lines = (files / "mm.csv").read_text().splitlines()
    rows = [r.split(",") for r in lines[1:]]
    inches = [r[:7] + [repr(float(v) / 25.4) for v in r[7:10]] + r[10:] for r in rows]
    (files / "in.csv").write_text("\n".join([lines[0]] + [",".join(r) for r in inches]) + "\n")
    capsys.readouterr()
    code, out = _fit(files, "in")
    err = capsys.readouterr().err
    assert code == 2 and not out.exists() and len(err.strip().splitlines()) == 1
    assert "look like inches read as mm; convert them to mm (x 25.4)" in err and "--length-unit" not in err


@pytest.mark.parametrize("convert, words", [
    (lambda c: c * 1.8 + 32, "they look like degrees Fahrenheit (degC = (F - 32) / 1.8)"),
    (lambda c: c + 273.15, "they look like kelvin (degC = K - 273.15)")])
def test_temperatures_in_another_scale_are_named(tmp_path, capsys, convert, words):
    """temp_c in Fahrenheit or kelvin was read as degC in silence (thermal_expansion's
    coefficients 1.8x off, the offset from 20 degC moved into the link lengths): one warning
    line naming the scale; the degC file reads quietly."""
    import warnings

    from torchcal.io.measurement_csv import ConditionWarning, read_measurements

    lines = (Path(__file__).resolve().parents[1] / "examples" / "ur10" / "series_c.csv").read_text().splitlines()[:41]
    col = lines[0].split(",").index("temp_c")
    rows = [line.split(",") for line in lines[1:]]
    for r in rows:
        r[col] = repr(convert(float(r[col])))
    (tmp_path / "t.csv").write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    with pytest.warns(ConditionWarning, match=r"t.csv: column temp_c: 40 of 40 row\(s\) outside -30..60 degC "
                                                rf"\(first: line 2, .*\): {re.escape(words)}; temp_c is in degrees"):
        read_measurements(tmp_path / "t.csv", n_joints=6)
    (tmp_path / "c.csv").write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConditionWarning)
        read_measurements(tmp_path / "c.csv", n_joints=6)


def test_payloads_in_grams_are_named(tmp_path):
    """payload_kg in grams (5000 for a 5 kg load on a 10 kg UR10) was read as 5 t in silence,
    scaling every load-driven effect: one warning line; kg read quietly."""
    import warnings

    from torchcal.io.measurement_csv import ConditionWarning, read_measurements

    ur10 = torchcal.robot(Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json")
    lines = (Path(__file__).resolve().parents[1] / "examples" / "ur10" / "series_c.csv").read_text().splitlines()[:21]
    for name, kg in (("g.csv", "5000.0"), ("kg.csv", "5.0")):
        (tmp_path / name).write_text("\n".join([lines[0] + ",payload_kg"] + [f"{r},{kg}" for r in lines[1:]]) + "\n")
    with pytest.warns(ConditionWarning, match=r"g.csv: column payload_kg: 20 of 20 row\(s\) above 3 times the rated "
                                              r"payload of ur10 \(10 kg; first: line 2, 5000; up to 5000\): grams read"):
        read_measurements(tmp_path / "g.csv", robot=ur10)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConditionWarning)
        read_measurements(tmp_path / "kg.csv", robot=ur10)


def test_a_frozen_reading_is_named(tmp_path):
    """12 rows repeating one x, y, z at other joint values (a tracker that lost the
    reflector, a cell filled down) were only 'gross outliers' at the fit: the reader names
    them in one warning line."""
    from torchcal.io.measurement_csv import CopiedRowWarning, read_measurements

    lines = (Path(__file__).resolve().parents[1] / "examples" / "ur10" / "series_c.csv").read_text().splitlines()[:61]
    xi = lines[0].split(",").index("x")
    rows = [line.split(",") for line in lines[1:]]
    for r in rows[30:42]:
        r[xi:xi + 3] = rows[29][xi:xi + 3]
    (tmp_path / "f.csv").write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    with pytest.warns(CopiedRowWarning, match=r"f.csv: 12 of 60 row\(s\) repeat an earlier row's x,y,z to every digit "
                                              r"at other joint values \(first: line 32, the x,y,z of line 31\)"):
        read_measurements(tmp_path / "f.csv", n_joints=6)
