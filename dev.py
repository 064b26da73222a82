#!/usr/bin/env python3
"""Set up and run rig from a fresh clone: `python3 dev.py demo` or `python3 dev.py test`
(`python3 dev.py test --quick`: the inner loop, under a minute: no real-time, trial or slow tests).

Creates .venv/ beside this file (once), installs rig into it (again whenever pyproject.toml
changes), then runs the demo or the test suite. Needs only Python 3.11+.
Extra arguments are passed on: `python3 dev.py demo --full-resolution`, `python3 dev.py test -k fit`.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
STAMP = VENV / ".rig-installed"


#: system packages (Debian names) and how to tell they are there: libusb for pyrealsense2,
#: tmux for the test that drives `rig tui` in a real terminal, strace for the tests that fill the disk at one
#: system call (tests/test_disk_full.py: ENOSPC injected by the kernel)
SYSTEM_PACKAGES = {"libusb-1.0-0": lambda: _has_library("libusb-1.0.so.0"), "tmux": lambda: shutil.which("tmux") is not None,
                   "strace": lambda: shutil.which("strace") is not None}


def _has_library(name: str) -> bool:
    out = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout if shutil.which("ldconfig") else ""
    return name in out or any(Path(d, name).exists() for d in ("/usr/lib/x86_64-linux-gnu", "/usr/lib", "/lib/x86_64-linux-gnu"))


def system_packages() -> None:
    """Install missing system packages with apt-get when we are root on Debian/Ubuntu; else say what to run."""
    missing = [pkg for pkg, present in SYSTEM_PACKAGES.items() if not present()]
    if not missing:
        return
    cmd = ["apt-get", "install", "-y", "--no-install-recommends", *missing]
    if hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("apt-get"):
        print(f"dev.py: installing system packages: {' '.join(missing)}", flush=True)
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        subprocess.run(["apt-get", "update", "-qq"], check=True, env=env, stdout=subprocess.DEVNULL)
        subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    else:
        print(f"dev.py: missing system packages {', '.join(missing)}; install them with: sudo {' '.join(cmd)}", flush=True)


def setup() -> None:
    if sys.version_info < (3, 11):
        sys.exit(f"rig needs Python 3.11 or newer; this is {sys.version.split()[0]}. Install a newer Python and re-run.")
    system_packages()
    if not (BIN / "python").exists():
        print(f"dev.py: creating {VENV}", flush=True)
        venv.EnvBuilder(with_pip=True).create(VENV)
    want = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if not STAMP.exists() or STAMP.read_text() != want:
        print("dev.py: installing rig and its dependencies into .venv (first run takes a minute)", flush=True)
        subprocess.run([str(BIN / "python"), "-m", "pip", "install", "--quiet", "--upgrade", "pip"], check=True)
        # --no-compile: Python compiles a module's bytecode when it is first imported; pip would compile every file of
        # scipy, matplotlib, numba ... up front (~25 s of CPU), most of which nothing here ever imports
        subprocess.run([str(BIN / "python"), "-m", "pip", "install", "--quiet", "--no-compile", "-e", f"{ROOT}[test,oak]"],
                       check=True)
        STAMP.write_text(want)


def child_env() -> dict[str, str]:
    """The environment for everything dev.py starts. PYTHONDONTWRITEBYTECODE=1 (set on some CI images) would make every
    Python process compile every module it imports from source, each time: with pip's --no-compile nothing is ever
    cached, and importing rig with numpy, scipy, h5py and matplotlib costs 3.8 s of CPU instead of 1.7 s, in each of
    the test suite's hundreds of processes. Bytecode then goes to .venv/pycache instead (PYTHONPYCACHEPREFIX), so the
    source tree stays as clean as the setting meant it to."""
    env = dict(os.environ)
    if env.pop("PYTHONDONTWRITEBYTECODE", None) is not None:
        env.setdefault("PYTHONPYCACHEPREFIX", str(VENV / "pycache"))
    return env


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("demo", "test", "setup"):
        print(__doc__.strip())
        return 2
    setup()
    cmd, rest = argv[0], argv[1:]
    if cmd == "setup":
        print(f"dev.py: ready; run {BIN / 'rig'} --help")
        return 0
    if cmd == "demo":
        return subprocess.call([str(BIN / "rig"), "demo", *rest], env=child_env())
    if not rest:  # the whole suite: numba's kernels compiled once here, not by every worker at once (tests/warm_kernels.py)
        subprocess.call([str(BIN / "python"), str(ROOT / "tests" / "warm_kernels.py")], cwd=ROOT, stdout=subprocess.DEVNULL,
                        env=child_env())
    return subprocess.call([str(BIN / "python"), "-m", "pytest", *rest], cwd=ROOT, env=child_env())


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
