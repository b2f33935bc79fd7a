"""Measurement CSV: round trips, one test per bad-file error, property-based tests."""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from torchcal.errors import InputError
from torchcal.measurements import Measurements
from torchcal.io.measurement_csv import (CopiedRowWarning, JointLimitWarning, PoseIdWarning, format_measurements, read_measurements,
                                         write_measurements)
from torchcal.io.robot_file import robot

HEADER6 = "pose,q1,q2,q3,q4,q5,q6,x,y,z"
ROW6 = "0,10,-20,30,0,45,90,1500.5,-2.25,1800"


def _write(tmp_path, text, name="data.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _meas(N=4, n=6, payload=False, temp=False, seed=0):
    g = torch.Generator().manual_seed(seed)
    return Measurements(
        pose=torch.arange(N) // 2,
        q=(torch.rand(N, n, generator=g, dtype=torch.float64) - 0.5) * 2.0,
        xyz=torch.randn(N, 3, generator=g, dtype=torch.float64) * 1000,
        payload_kg=torch.rand(N, generator=g, dtype=torch.float64) * 100 if payload else None,
        temp_c=20 + torch.randn(N, generator=g, dtype=torch.float64) if temp else None,
    )


def _assert_same(a: Measurements, b: Measurements, q_rtol=1e-14):
    assert torch.equal(a.pose, b.pose)
    assert b.pose.dtype == torch.int64 and b.q.dtype == torch.float64
    torch.testing.assert_close(b.q, a.q, rtol=q_rtol, atol=1e-15)
    assert torch.equal(a.xyz, b.xyz)
    for name in ("payload_kg", "temp_c"):
        va, vb = getattr(a, name), getattr(b, name)
        assert (va is None) == (vb is None)
        if va is not None:
            assert torch.equal(va, vb)


# -- round trips ----------------------------------------------------------------------

@pytest.mark.parametrize("payload", [False, True])
@pytest.mark.parametrize("temp", [False, True])
def test_round_trip(tmp_path, payload, temp):
    m = _meas(payload=payload, temp=temp)
    p = write_measurements(tmp_path / "m.csv", m)
    header = p.read_text().splitlines()[0]
    assert header == HEADER6 + (",payload_kg" if payload else "") + (",temp_c" if temp else "")
    back = read_measurements(p, robot=robot("ur5e"))
    _assert_same(m, back)
    assert back.source == str(p)
    # deterministic: writing what was read gives the same text
    assert format_measurements(back) == p.read_text()


def test_read_degrees_to_radians_any_column_order(tmp_path):
    p = _write(tmp_path, "x,y,z,q2,q1,pose,temp_c\n1,2,3,90,-180,7,21.5\n4,5,6,0,45,7.0,22\n")
    m = read_measurements(p)
    assert len(m) == 2 and m.n == 2
    assert m.pose.tolist() == [7, 7]
    torch.testing.assert_close(m.q_deg, torch.tensor([[-180.0, 90.0], [45.0, 0.0]], dtype=torch.float64))
    torch.testing.assert_close(m.q[0, 0], torch.tensor(-math.pi, dtype=torch.float64))
    assert m.xyz.tolist() == [[1, 2, 3], [4, 5, 6]]
    assert m.payload_kg is None and m.temp_c.tolist() == [21.5, 22.0]


def test_blank_lines_bom_crlf_spaces(tmp_path):
    p = tmp_path / "d.csv"
    p.write_bytes(("\ufeff pose , q1 ,x,y,z\r\n\r\n1, 2.5 ,3,4,5\r\n\r\n").encode("utf-8"))
    m = read_measurements(p)
    assert len(m) == 1 and m.q_deg.tolist() == [[2.5]]


def test_q_prev_and_subset_keep_order():
    m = _meas(N=5, n=2)
    torch.testing.assert_close(m.q_prev[0], torch.zeros(2, dtype=torch.float64))
    torch.testing.assert_close(m.q_prev[1:], m.q[:-1])
    s = m.subset(torch.tensor([4, 1, 3]))
    assert len(s) == 3
    assert torch.equal(s.q, m.q[[1, 3, 4]])  # file order, whatever the index order
    assert torch.equal(s.q_prev, m.q[[0, 2, 3]])  # true predecessors are kept
    mask = torch.tensor([True, False, True, False, False])
    assert torch.equal(m.subset(mask).xyz, m.xyz[[0, 2]])
    assert torch.equal(m.subset(slice(1, 3)).pose, m.pose[1:3])
    assert torch.equal(m.subset([-1]).pose, m.pose[-1:])
    with pytest.raises(ValueError, match=r"row indices must lie in \[-5, 5\)"):
        m.subset([5])
    with pytest.raises(ValueError, match=r"bool mask must have shape \(5,\)"):
        m.subset(torch.tensor([True]))


def test_measurements_checks_fields():
    with pytest.raises(ValueError, match=r"Measurements\.xyz: expected shape \(2, 3\) mm"):
        Measurements(torch.arange(2), torch.zeros(2, 6), torch.zeros(2, 2))
    with pytest.raises(ValueError, match=r"Measurements\.q: values must be finite"):
        Measurements(torch.arange(1), torch.tensor([[float("nan")]]), torch.zeros(1, 3))
    with pytest.raises(ValueError, match=r"Measurements\.payload_kg: payload must be >= 0 kg"):
        Measurements(torch.arange(1), torch.zeros(1, 1), torch.zeros(1, 3), payload_kg=torch.tensor([-1.0]))
    with pytest.raises(ValueError, match=r"Measurements\.pose: expected integer pose ids"):
        Measurements(torch.zeros(1), torch.zeros(1, 1), torch.zeros(1, 3))


def test_write_refuses_existing_and_input(tmp_path):
    m = _meas()
    p = write_measurements(tmp_path / "m.csv", m)
    with pytest.raises(ValueError, match="output exists"):
        write_measurements(p, m)
    back = read_measurements(p)
    with pytest.raises(ValueError, match="refusing to write over the input file"):
        write_measurements(p, back, force=True)
    write_measurements(p, m, force=True)


# -- bad files: each error names the file, the place and the column ---------------------

BAD = [
    # (file text, message regex after the file name)
    ("", r"empty file; expected a header line pose,q1"),
    ("\n  \n", r"empty file"),
    (HEADER6 + "\n", r"has a header but no data rows"),
    ("pose,q1,q2,q3,q4,q5,q6,x,y\n0,1,2,3,4,5,6,7,8\n", r"line 1: missing column z"),
    ("pose,q1,q2,q3,q4,q5,q6,x,z,y\n" + ROW6 + "\n", None),  # any order is fine
    ("pose,q1,q2,q3,q4,q6,q7,x,y,z\n" + ROW6 + "\n", r"line 1: missing column q5"),
    (HEADER6 + ",color\n" + ROW6 + ",red\n", r"line 1, column 'color' \(header column 11\): unknown column"),
    (HEADER6 + ",q1\n" + ROW6 + ",3\n", r"line 1, column 'q1': duplicated header column \(columns 2 and 11\)"),
    (HEADER6 + ",\n" + ROW6 + ",\n", r"line 1, header column 11: empty column name"),
    ("pose;q1;x;y;z\n0;1;2;3;4\n", r"line 1: expected comma-separated columns"),
    (ROW6 + "\n" + ROW6 + "\n", r"line 1: expected a header line .*looks like data"),
    (HEADER6 + "\n" + ROW6 + "\n1,2,3\n", r"line 3 \(data row 2\): expected 10 fields as in the header, found 3"),
    (HEADER6 + "\n" + ROW6 + ",9\n", r"line 2 \(data row 1\): expected 10 fields"),
    (HEADER6 + "\n" + ROW6.replace("-20", "abc") + "\n", r"line 2 \(data row 1\), column q2: expected a number \(degrees\), got 'abc'"),
    (HEADER6 + "\n" + ROW6.replace("-20", "") + "\n", r"line 2 \(data row 1\), column q2: expected a number \(degrees\), got an empty cell"),
    (HEADER6 + "\n" + ROW6 + "\n" + ROW6.replace("1800", "nan") + "\n", r"line 3 \(data row 2\), column z: expected a finite number \(mm\), got 'nan'"),
    (HEADER6 + "\n" + ROW6.replace("1800", "-inf") + "\n", r"line 2 \(data row 1\), column z: expected a finite number \(mm\), got '-inf'"),
    (HEADER6 + "\n" + ROW6.replace("1800", "1e999") + "\n", r"line 2 \(data row 1\), column z: expected a finite number"),
    (HEADER6 + "\n" + ROW6.replace("1500.5", "1_500") + "\n", r"line 2 \(data row 1\), column x: expected a number \(mm\), got '1_500'"),
    (HEADER6 + "\n" + "1.5" + ROW6[1:] + "\n", r"line 2 \(data row 1\), column pose: expected an integer pose id, got '1.5'"),
    (HEADER6 + "\n" + "p1" + ROW6[1:] + "\n", r"line 2 \(data row 1\), column pose: expected an integer pose id, got 'p1'"),
    (HEADER6 + "\n" + "9" * 30 + ROW6[1:] + "\n", r"line 2 \(data row 1\), column pose: pose id 9+ does not fit in a 64-bit integer"),
    (HEADER6 + ",payload_kg\n" + ROW6 + ",-1\n", r"line 2 \(data row 1\), column payload_kg: payload must be >= 0 kg, got '-1'"),
    (HEADER6 + ",temp_c\n" + ROW6 + ",\n", r"line 2 \(data row 1\), column temp_c: expected a number \(degC\), got an empty cell"),
    (HEADER6 + "\n\n" + ROW6 + "\n" + ROW6.replace("45", "x") + "\n", r"line 4 \(data row 2\), column q5"),
]


@pytest.mark.parametrize("text,match", BAD)
def test_bad_file(tmp_path, text, match):
    p = _write(tmp_path, text)
    if match is None:
        assert len(read_measurements(p, robot=robot("kr1000titan"))) == 1
        return
    with pytest.raises(ValueError, match=r"^.*data\.csv: " + match) as info:
        read_measurements(p, robot=robot("kr1000titan"))
    assert info.type is InputError
    assert "\n" not in str(info.value)


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(InputError, match=r"nope\.csv: measurement file does not exist"):
        read_measurements(tmp_path / "nope.csv")
    with pytest.raises(InputError, match="is not a regular file"):
        read_measurements(tmp_path)


def test_not_utf8(tmp_path):
    p = tmp_path / "data.csv"
    p.write_bytes(b"pose,q1,x,y,z\n0,\xff,1,2,3\n")
    with pytest.raises(InputError, match=r"data\.csv: not a UTF-8 text file"):
        read_measurements(p)


def test_joint_count_vs_robot(tmp_path):
    p = _write(tmp_path, "pose,q1,q2,q3,q4,q5,x,y,z\n0,1,2,3,4,5,6,7,8\n")
    with pytest.raises(InputError, match=r"data\.csv: line 1: expected 6 joints for robot "
                                         r"kr1000titan, found 5 q-columns \(q1, q2, q3, q4, q5\)"):
        read_measurements(p, robot=robot("kr1000titan"))
    with pytest.raises(InputError, match=r"expected 4 joints for the given n_joints, found 5"):
        read_measurements(p, n_joints=4)
    assert read_measurements(p).n == 5
    with pytest.raises(InputError, match=r"n_joints=5 disagrees with robot ur5e \(6 joints\)"):
        read_measurements(p, n_joints=5, robot=robot("ur5e"))
    with pytest.raises(InputError, match=r"n_joints must be a positive integer, got 0"):
        read_measurements(p, n_joints=0)


def test_joint_limits_warn_or_fail(tmp_path):
    # kr1000titan q2 limits are -130..17.5 deg: 20 is outside, 17.5 (the limit) is inside
    p = _write(tmp_path, HEADER6 + "\n" + ROW6 + "\n" + "1" + ROW6.replace("-20", "17.5")[1:] + "\n"
               + "2" + ROW6.replace("-20", "20")[1:] + "\n")  # three poses, three ids
    with pytest.warns(JointLimitWarning, match=r"data\.csv: 1 row\(s\) outside the joint limits of "
                                               r"robot kr1000titan: line 4 q2=20 deg \(limits -130\.\.17\.5\)"):
        m = read_measurements(p, robot=robot("kr1000titan"))
    assert len(m) == 3
    with pytest.raises(InputError, match=r"line 4 q2=20 deg"):
        read_measurements(p, robot=robot("kr1000titan"), strict_limits=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_measurements(p)  # no robot, no limits to check


def test_pose_id_repeated_at_other_joint_values_warns(tmp_path):
    """Two files joined with restarting pose ids: rows of one id at other joint values are
    no repeats of one pose, yet folds, split and the noise floor would take them as one.
    A PoseIdWarning names the first such row; true repeats (the same values, or measured
    angles a few thousandths of a degree apart) read silently."""
    other = "0,11,-20,30,0,45,90,1500.5,-2.25,1800"  # pose id 0 again, q1 11 instead of 10
    p = _write(tmp_path, HEADER6 + "\n" + ROW6 + "\n1" + ROW6[1:] + "\n" + other + "\n")
    with pytest.warns(PoseIdWarning, match=r"data\.csv: 1 row\(s\) repeat a pose id at other joint values "
                                           r"\(first: line 4, pose id 0, q1=11 degrees, on line 2 10\)"):
        assert len(read_measurements(p)) == 3
    jitter = ROW6.replace(",10,", ",10.003,")
    noisy = ROW6.replace(",1500.5,", ",1500.51,")  # a repeat: the same joints, x by the tracker's noise
    q = _write(tmp_path, HEADER6 + "\n" + ROW6 + "\n" + noisy + "\n" + jitter + "\n", "repeats.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_measurements(q).pose.tolist() == [0, 0, 0]
    rad = _write(tmp_path, HEADER6 + "\n" + ROW6 + "\n" + other.replace("0,11,", "0,10.01,") + "\n", "rad.csv")
    with pytest.warns(PoseIdWarning, match=r"q1=10\.01 rad, on line 2 10\)"):  # 0.01 rad > 0.1 deg
        read_measurements(rad, angle_unit="rad")


def test_rows_copied_to_every_digit_warn(tmp_path):
    """A block pasted twice (joints and x, y, z equal to every written digit, the point id
    too) is one CopiedRowWarning naming the first copy: the copies were read silently as
    repeats (a noise floor of 0 from them, their rows weighed twice). A repeat that differs
    by the tracker's noise, or a copy at another point id, reads silently."""
    other = "1,11,-20,30,0,45,90,1600.5,-2.25,1800"
    p = _write(tmp_path, HEADER6 + "\n" + ROW6 + "\n" + other + "\n" + ROW6 + "\n" + other + "\n")
    with pytest.warns(CopiedRowWarning, match=r"data\.csv: 2 of 4 row\(s\) copy an earlier row's joint values and "
                                              r"x,y,z to every digit \(first: line 4 = line 2\)"):
        assert len(read_measurements(p)) == 4
    points = _write(tmp_path, HEADER6 + ",point\n" + ROW6 + ",1\n" + ROW6 + ",2\n", "points.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_measurements(points).point.tolist() == [1, 2]


# -- property-based ---------------------------------------------------------------------

_finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
_FAST = settings(max_examples=60, deadline=None,
                 suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@st.composite
def measurements(draw):
    N = draw(st.integers(1, 6))
    n = draw(st.integers(1, 7))
    col = lambda k, el=_finite: draw(st.lists(el, min_size=k, max_size=k))  # noqa: E731
    q_deg = torch.tensor([col(n, st.floats(-720, 720, allow_nan=False)) for _ in range(N)], dtype=torch.float64)
    return Measurements(
        pose=torch.tensor(col(N, st.integers(-(2 ** 63), 2 ** 63 - 1)), dtype=torch.int64),
        q=torch.deg2rad(q_deg),
        xyz=torch.tensor([col(3) for _ in range(N)], dtype=torch.float64),
        payload_kg=draw(st.none() | st.just(torch.tensor(col(N, st.floats(0, 1e4)), dtype=torch.float64))),
        temp_c=draw(st.none() | st.just(torch.tensor(col(N, st.floats(-50, 200)), dtype=torch.float64))),
    )


@_FAST
@given(m=measurements())
def test_property_round_trip(tmp_path_factory, m):
    p = tmp_path_factory.mktemp("rt") / "m.csv"
    write_measurements(p, m)
    back = read_measurements(p, n_joints=m.n)
    _assert_same(m, back)
    assert format_measurements(back) == p.read_text()


def _read_only_inputerror(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            read_measurements(path, robot=robot("puma560"))
        except InputError as exc:
            assert "\n" not in str(exc)
            assert str(path) in str(exc)


@_FAST
@given(text=st.text(alphabet=st.sampled_from(list("pose,qxyz123456789-.e\n \tnaif_;\"'\x00é")), max_size=200)
       | st.text(max_size=200))
def test_property_garbage_only_inputerror(tmp_path_factory, text):
    p = tmp_path_factory.mktemp("g") / "g.csv"
    p.write_text(text)
    _read_only_inputerror(p)


@_FAST
@given(data=st.data())
def test_property_cell_corruption_only_inputerror(tmp_path_factory, data):
    m = _meas(N=3, payload=True, temp=True)
    lines = [line.split(",") for line in format_measurements(m).splitlines()]
    for _ in range(data.draw(st.integers(1, 3))):
        r = data.draw(st.integers(0, len(lines) - 1))
        c = data.draw(st.integers(0, len(lines[r]) - 1))
        junk = data.draw(st.sampled_from(["", "nan", "inf", "-1", "1e999", "q1", "pose", "1,2", "\"",
                                          "9" * 40, "1.5", " ", "x"]) | st.text(max_size=8))
        action = data.draw(st.sampled_from(["replace", "delete", "insert"]))
        if action == "replace":
            lines[r][c] = junk
        elif action == "delete":
            del lines[r][c]
        else:
            lines[r].insert(c, junk)
    p = tmp_path_factory.mktemp("c") / "c.csv"
    p.write_text("\n".join(",".join(cells) for cells in lines) + "\n")
    _read_only_inputerror(p)


def test_library_overwrite_error_names_no_cli_flag(tmp_path):
    """io.files says the output exists (OutputExistsError); only the CLI adds --force."""
    from torchcal.errors import OutputExistsError
    from torchcal.io.files import write_json

    path = tmp_path / "a.json"
    write_json(path, {"a": 1})
    with pytest.raises(OutputExistsError) as info:
        write_json(path, {"a": 2})
    assert "--force" not in str(info.value) and str(info.value).endswith("output exists")
    write_json(path, {"a": 2}, force=True)
    assert path.read_text().count('"a": 2') == 1


def test_orientation_written_in_degrees_under_its_header(tmp_path):
    """rx, ry, rz columns hold degrees (the header's unit), read off the text here, and read
    back to the same radians."""
    import csv

    rxyz = torch.tensor([[math.pi / 2, -math.pi / 6, 0.25], [0.0, math.pi / 4, -math.pi]], dtype=torch.float64)
    q = torch.deg2rad(torch.tensor([[10.0, -20.0, 30.0, 0.0, 45.0, 90.0], [0.0] * 6], dtype=torch.float64))
    m = Measurements(torch.arange(2), q, torch.tensor([[1000.0, 0.0, 500.0], [900.0, 10.0, 400.0]]), rxyz=rxyz)
    path = write_measurements(tmp_path / "rot.csv", m)
    rows = list(csv.DictReader(open(path, newline="")))
    got = [[float(r[c]) for c in ("rx", "ry", "rz")] for r in rows]
    assert got[0] == pytest.approx([90.0, -30.0, math.degrees(0.25)], abs=1e-12)
    assert got[1] == pytest.approx([0.0, 45.0, -180.0], abs=1e-12)
    assert [float(rows[0][f"q{k}"]) for k in range(1, 7)] == pytest.approx([10.0, -20.0, 30.0, 0.0, 45.0, 90.0])
    back = read_measurements(path)
    torch.testing.assert_close(back.rxyz, rxyz, rtol=0, atol=1e-14)


def test_check_output_refuses_a_folder_even_with_force(tmp_path):
    """The one overwrite rule (also viz's): a folder is never an output file."""
    from torchcal.errors import OutputExistsError
    from torchcal.io.files import check_output

    (tmp_path / "d").mkdir()
    for force in (False, True):  # named as a folder first: force would not help (tests/test_files.py)
        with pytest.raises(InputError, match="is a folder, expected a file name") as info:
            check_output(tmp_path / "d", force=force)
        assert not isinstance(info.value, OutputExistsError)
    assert check_output(tmp_path / "new.csv") == tmp_path / "new.csv"
