"""The command-line shell: version, help, module entry point, error mapping."""

from __future__ import annotations

import subprocess
import sys

import pytest

import voxflex
from voxflex.cli import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert voxflex.__version__ in capsys.readouterr().out


def test_no_command_prints_help(capsys):
    assert main([]) == 2  # no command: the help, and a usage error's status
    out = capsys.readouterr().out
    assert "usage: voxflex" in out and "quick start" in out


def test_python_dash_m_runs_the_cli():
    proc = subprocess.run(
        [sys.executable, "-m", "voxflex", "--version"], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0
    assert proc.stdout.strip() == f"voxflex {voxflex.__version__}"


def test_unknown_public_name():
    with pytest.raises(AttributeError):
        voxflex.does_not_exist  # noqa: B018


def test_public_functions_are_not_shadowed_by_their_modules():
    # importing the implementing modules must not replace vf.simulate / vf.render
    import voxflex.rendering  # noqa: F401
    import voxflex.simulation  # noqa: F401

    assert voxflex.simulate.__name__ == "simulate" and callable(voxflex.simulate)
    assert voxflex.render.__name__ == "render" and callable(voxflex.render)
