"""The output rule of `torchcal.io.files.check_output`: an output that exists but is no
regular file (a device, a named pipe) is refused, `force` or not, since the atomic
rename would replace the node itself (``--out /dev/full --force`` replaced the device
with the model file)."""

from __future__ import annotations

import json
import os

import pytest

from torchcal.errors import InputError
from torchcal.io.files import atomic_write, check_output


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes need POSIX")
def test_a_named_pipe_is_not_replaced_even_with_force(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match=r"pipe: not a regular file \(a device, pipe or socket\)"):
        atomic_write(fifo, "data", force=True)
    assert fifo.is_fifo() and sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]
    plain = tmp_path / "plain.txt"  # a regular file of that kind is still replaced with force
    plain.write_text("old")
    assert check_output(plain, force=True) == plain
    atomic_write(plain, "new", force=True)
    assert plain.read_text() == "new"


@pytest.mark.parametrize("text, must", [
    ("pose,q1,q2,x,y,z\n0,1,2,3,4,5\n", r"m\.json: not a valid model file: a CSV table \(first line 'pose,q1,q2,x,y,z'\), "
                                         r"not JSON"),
    ("\ufeffx,y,z\n1,2,3\n", r"a CSV table \(first line 'x,y,z'\)"),
    ("", r"m\.json: not a valid model file: the file is empty"),
    ("  \n", r"the file is empty"),
    ('{"a":\n', r"not a valid model file: Expecting value: line 2"),  # broken JSON: the parser's place
])
def test_read_json_names_a_csv_or_an_empty_file(tmp_path, text, must):
    """A CSV given where a JSON file belongs (the data as --model or --robot) or an empty
    file is named as such, not as 'Expecting value: line 1 column 1 (char 0)'."""
    from torchcal.io.files import read_json

    p = tmp_path / "m.json"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=must):
        read_json(p, "model file")


def test_read_json_reads_a_byte_order_mark_and_windows_line_ends(tmp_path):
    """A JSON file saved by a Windows editor (UTF-8 with a byte order mark, CRLF line ends)
    reads as its content ('Unexpected UTF-8 BOM' before)."""
    from torchcal.io.files import read_json

    p = tmp_path / "m.json"
    p.write_bytes('\ufeff{\r\n  "format": "x",\r\n  "n": 3\r\n}\r\n'.encode("utf-8"))
    assert read_json(p, "model file") == {"format": "x", "n": 3}


def test_an_output_that_is_a_folder_is_named_as_one(tmp_path):
    """torchcal.save(res, FOLDER) said 'output exists' (and --force then 'is a folder')."""
    from torchcal.errors import InputError, OutputExistsError
    from torchcal.io.files import check_output

    (tmp_path / "out").mkdir()
    with pytest.raises(InputError, match=r"out: is a folder, expected a file name$") as info:
        check_output(tmp_path / "out")
    assert not isinstance(info.value, OutputExistsError)


def test_read_json_refuses_a_key_given_twice(tmp_path):
    """A robot file with two "tool" matrices (an edit pasted below the old one): JSON keeps
    the last in silence, so the fit used a tool the user may have meant to replace; one
    line names the key and its lines (before: read, the first tool dropped)."""
    from torchcal.io.robot_file import robot_to_dict

    import torchcal
    from torchcal import cli

    obj = robot_to_dict(torchcal.robot("ur5e"))
    text = json.dumps(obj, indent=1)
    tool = '"tool": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 120], [0, 0, 0, 1]],\n '
    text = text.replace('"payload_kg"', tool + '"payload_kg"')
    p = tmp_path / "r.json"
    p.write_text(text, encoding="utf-8")
    lines = [i + 1 for i, ln in enumerate(text.splitlines()) if '"tool":' in ln]
    assert len(lines) == 2
    with pytest.raises(InputError, match=rf"key 'tool' given twice in one object \(the key is on lines "
                                         rf"{lines[0]}, {lines[1]}\)"):
        torchcal.robot(p)
    out = tmp_path / "m.json"
    assert cli.main(["plan", "--robot", str(p), "--n", "10", "--out", str(out)]) == 2
    assert not out.exists()
    nested = tmp_path / "n.json"  # a key twice inside a joint
    nested.write_text(json.dumps(obj).replace('"d_mm": 0.0,', '"d_mm": 0.0, "d_mm": 5.0,', 1), encoding="utf-8")
    with pytest.raises(InputError, match="key 'd_mm' given twice"):
        torchcal.robot(nested)
