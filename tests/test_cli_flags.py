"""`rig --version`, `rig.__version__` and the -v/-q every command takes, through the installed console script."""

import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import rig
from rig.cli import build_parser
import pytest

pytestmark = pytest.mark.slow


RIG = Path(sys.executable).parent / "rig"


def test_version_comes_from_the_installed_package():
    assert rig.__version__ == version("rig")
    r = subprocess.run([str(RIG), "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == f"rig {version('rig')}"


def test_verbosity_flags_go_before_or_after_the_command():
    p = build_parser()
    assert p.parse_args(["-q", "fit", "x.h5"]).quiet and p.parse_args(["fit", "x.h5", "-q"]).quiet
    assert p.parse_args(["-vv", "diagnose", "x.h5"]).verbose == 2
    assert p.parse_args(["compare", "x.h5", "--models", "active", "-v"]).verbose == 1
    assert p.parse_args(["-v", "stage-sim", "grbl"]).verbose == 1  # stage-sim's -v (print the traffic) is the same flag
    plain = p.parse_args(["fit", "x.h5"])
    assert plain.verbose == 0 and not plain.quiet


def test_quiet_run_prints_nothing_on_stderr(tmp_path):
    args = ["run", "--protocol", "perpendicular", "--frames", "3", "--stops", "0.5,1.0", "--camera", "fake:width=16"]
    loud = subprocess.run([str(RIG), *args, "-o", str(tmp_path / "a.h5")], capture_output=True, text=True)
    quiet = subprocess.run([str(RIG), "-q", *args, "-o", str(tmp_path / "b.h5")], capture_output=True, text=True)
    assert loud.returncode == 0 and quiet.returncode == 0, loud.stderr + quiet.stderr
    assert "0.500m done" in loud.stderr and quiet.stderr == ""
    assert "recorded 2 stops" in quiet.stdout  # the result itself is not chatter
