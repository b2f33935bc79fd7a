"""The output rule of `torchcal.io.files.check_output`: an output that exists but is no
regular file (a device, a named pipe) is refused, `force` or not, since the atomic
rename would replace the node itself (``--out /dev/full --force`` replaced the device
with the model file)."""

from __future__ import annotations

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
