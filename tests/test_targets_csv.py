"""The compensation targets CSV (`torchcal.io.targets_csv.read_targets`): what a
spreadsheet writes is read as the measurement CSV is (byte order mark, blank lines), and
every malformed file is one InputError naming the file and what is wrong, never a
UnicodeDecodeError / csv.Error, nor a silently chosen column."""

from __future__ import annotations

import pytest
import torch

from torchcal.errors import InputError
from torchcal.io.targets_csv import read_targets


def _write(tmp_path, data: bytes, name="t.csv"):
    p = tmp_path / name
    p.write_bytes(data)
    return p


@pytest.mark.parametrize("data", [
    b"\xef\xbb\xbfx,y,z\n400,100,500\n-300,20,600\n",   # Excel's UTF-8 byte order mark
    b"\n\nx,y,z\n400,100,500\n\n-300,20,600\n",          # blank lines before the header
    b"x,y,z\r\n400,100,500\r\n-300,20,600\r\n",           # CRLF
])
def test_spreadsheet_variants_read_as_the_plain_file(tmp_path, data):
    t, seeds, _ = read_targets(_write(tmp_path, data), 6)
    assert seeds is None
    assert torch.equal(t, torch.tensor([[400.0, 100, 500], [-300, 20, 600]], dtype=torch.float64))


@pytest.mark.parametrize("data, match", [
    (b"x,y,z,x\n400,100,500,0\n", r"t\.csv: column 'x': duplicated header column \(columns 1 and 4\)"),
    (b"x,y,z\n400,100,500\xff\n", r"t\.csv: not a UTF-8 text file \(byte 17\)"),
    (b'x,y,z\n"400,100,500\n', r"t\.csv: line 2: not valid CSV"),
    (b"\n \n", r"t\.csv: empty file"),
    (b"\nx,y,z\n400,100,500\n\n1,2,a\n", r"t\.csv: line 5, column z: expected a number \(mm\), got 'a'"),
])
def test_malformed_targets_one_inputerror(tmp_path, data, match):
    with pytest.raises(InputError, match=match):
        read_targets(_write(tmp_path, data), 6)


def test_a_folder_is_not_called_missing(tmp_path):
    with pytest.raises(InputError, match="targets file is not a regular file"):
        read_targets(tmp_path, 6)
    with pytest.raises(InputError, match="targets file does not exist"):
        read_targets(tmp_path / "none.csv", 6)


def test_target_temperatures_in_fahrenheit_are_named(tmp_path):
    """temp_c of targets in Fahrenheit was read as degC in silence (a thermal model then
    compensates for 50 degrees too warm): one warning line, as for measurements."""
    from torchcal.io.measurement_csv import ConditionWarning

    (tmp_path / "t.csv").write_text("x,y,z,temp_c\n500,0,600,71.6\n550,10,620,72.5\n")
    with pytest.warns(ConditionWarning, match=r"t.csv: column temp_c: 2 of 2 row\(s\) outside -30..60 degC \(first: "
                                              r"line 2, 71.6; median 72.5\): they look like degrees Fahrenheit"):
        read_targets(tmp_path / "t.csv", 6)


def test_a_measurement_file_given_as_targets_is_named(tmp_path):
    (tmp_path / "m.csv").write_text("pose,q1,q2,q3,q4,q5,q6,x,y,z\n0,1,2,3,4,5,6,500,0,600\n")
    with pytest.raises(InputError, match=r"m.csv: unknown column\(s\) pose \(a measurement file\? targets are the "
                                         r"positions to reach\); expected x,y,z"):
        read_targets(tmp_path / "m.csv", 6)
