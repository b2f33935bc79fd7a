"""The Makefile's set-up targets, by make's dry run (-n) in a copy: nothing is installed."""

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _copy(tmp_path):
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    for name in ("Makefile", "pyproject.toml"):
        shutil.copy(ROOT / name, tmp_path / name)


def _dry_run(tmp_path, target):
    return subprocess.run(["make", "-n", target], cwd=tmp_path, capture_output=True, text=True)


def test_make_venv_creates_and_installs_when_missing(tmp_path):
    _copy(tmp_path)
    r = _dry_run(tmp_path, ".venv")
    assert r.returncode == 0, r.stderr
    assert "python3 -m venv .venv" in r.stdout
    assert "pip install -q -e '.[dev]'" in r.stdout
    assert ". .venv/bin/activate" in r.stdout  # says how to put torchcal on the PATH


def test_make_venv_installs_nothing_when_present(tmp_path):
    _copy(tmp_path)
    (tmp_path / ".venv").mkdir()
    (tmp_path / ".venv" / ".installed").touch()  # newer than pyproject.toml
    r = _dry_run(tmp_path, ".venv")
    assert r.returncode == 0, r.stderr
    assert "pip install" not in r.stdout and "python3 -m venv" not in r.stdout
