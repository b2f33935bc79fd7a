"""The command line's self-description: --version, and complete --help texts."""

import importlib

import pytest

import torchcal
from torchcal import cli


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"torchcal {torchcal.__version__}"


@pytest.mark.parametrize("name", cli.COMMANDS)
def test_help_is_the_whole_module_docstring(name, capsys):
    """Each command's --help carries its module docstring to the end (no cut sentences)."""
    with pytest.raises(SystemExit) as exc:
        cli.main([name, "--help"])
    assert exc.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    doc = importlib.import_module(f"torchcal.cli.{name}").__doc__
    last_paragraph = " ".join(doc.strip().split("\n\n")[-1].split())
    assert last_paragraph in out


def test_top_level_help_lists_every_command_and_effect(capsys):
    from torchcal.effects import REGISTRY

    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    for name in cli.COMMANDS:
        assert f"\n    {name}" in out
    for effect in REGISTRY:
        assert effect in out
