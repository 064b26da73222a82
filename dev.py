#!/usr/bin/env python3
"""Set up and run rig from a fresh clone: `python3 dev.py demo` or `python3 dev.py test`.

Creates .venv/ beside this file (once), installs rig into it (again whenever pyproject.toml
changes), then runs the demo or the test suite. Needs only Python 3.11+.

  python3 dev.py test             the whole suite, then its numeric tests again on other floating-point paths,
                                  the benchmark's quick tier (benchmarks/ci_tier.py: ratios printed, not judged),
                                  and the CPU each part took (by test file in .venv/suite-cpu.md)
  python3 dev.py test --quick     the inner loop, under a minute: the tests not marked slow
  python3 dev.py test --fp-paths  only the numeric tests, on other floating-point paths (docs/testing.md)

Extra arguments are passed on to the demo or to pytest: `python3 dev.py demo --full-resolution`,
`python3 dev.py test -k fit`.
"""

from __future__ import annotations

import hashlib
import os
import platform
import resource
import shutil
import subprocess
import sys
import time
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
STAMP = VENV / ".rig-installed"


#: system packages (Debian names) and how to tell they are there: libusb for pyrealsense2,
#: tmux for the test that drives `rig tui` in a real terminal, strace for the tests that fill the disk at one
#: system call (tests/test_disk_full.py: ENOSPC injected by the kernel), chromium for the test that looks at a report
#: as a browser lays it out (tests/test_report_pictures.py)
SYSTEM_PACKAGES = {"libusb-1.0-0": lambda: _has_library("libusb-1.0.so.0"), "tmux": lambda: shutil.which("tmux") is not None,
                   "strace": lambda: shutil.which("strace") is not None,
                   "chromium": lambda: shutil.which("chromium") is not None}


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
        install(f"{ROOT}[test,oak]")
        STAMP.write_text(want)


def install(requirement: str) -> None:
    """`pip install -e requirement` into .venv, by uv where it installs (a pip package of a Rust installer: the
    dependencies' wheels unpacked in ~6 s of CPU where pip takes ~16 s with its own upgrade), else by pip. Neither
    compiles bytecode up front: Python compiles a module when it is first imported, and pip would compile every file
    of scipy, matplotlib, numba ... (~25 s of CPU), most of which nothing here ever imports."""
    python = str(BIN / "python")
    quiet = subprocess.run([python, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "uv"])
    uv = BIN / ("uv.exe" if os.name == "nt" else "uv")
    if quiet.returncode == 0 and uv.exists() and subprocess.run(
            [str(uv), "pip", "install", "--quiet", "--python", python, "-e", requirement]).returncode == 0:
        return
    print("dev.py: uv could not install; installing with pip", flush=True)
    subprocess.run([python, "-m", "pip", "install", "--quiet", "--upgrade", "pip"], check=True)
    subprocess.run([python, "-m", "pip", "install", "--quiet", "--no-compile", "-e", requirement], check=True)


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


def other_fp_env(python: Path) -> dict[str, str]:
    """Settings that move this machine's floating point onto other code paths, as another processor would take
    them (docs/testing.md): numba compiles for a generic CPU of the architecture (no FMA, no AVX), numpy's SIMD
    loops beyond its baseline are turned off (its transcendental functions then call the C library's), glibc's
    libm takes its variants without FMA and AVX2 (x86-64), and OpenBLAS its kernels for an older core. Each of
    them changes the last bits of some results (`exp`, `log`, `arccos`, matrix products) against the defaults."""
    found = subprocess.run([str(python), "-c", "import numpy as np; m = np._core._multiarray_umath if hasattr(np, '_core')"
                            " else np.core._multiarray_umath; print(' '.join(f for f in m.__cpu_dispatch__"
                            " if m.__cpu_features__.get(f)))"], capture_output=True, text=True).stdout.split()
    env = {"NUMBA_CPU_NAME": "generic", "NPY_DISABLE_CPU_FEATURES": " ".join(found)}
    if platform.machine() in ("x86_64", "AMD64"):
        env |= {"GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA,-AVX512F", "OPENBLAS_CORETYPE": "Nehalem"}
    elif platform.machine() in ("aarch64", "arm64"):
        env |= {"OPENBLAS_CORETYPE": "ARMV8"}
    return env


class CpuClock:
    """The CPU (user + system) of the processes this one has waited for, and the machine's busy time (/proc/stat,
    which also counts what no rusage sees: servers the tests start and do not wait for, and anything else)."""

    def __init__(self) -> None:
        self.rows: list[tuple[str, float, float, float]] = []
        self._last = self._now()

    @staticmethod
    def _now() -> tuple[float, float, float]:
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        busy = float("nan")
        try:
            ticks = [int(v) for v in Path("/proc/stat").read_text().split("\n")[0].split()[1:]]
            busy = (sum(ticks) - ticks[3] - (ticks[4] if len(ticks) > 4 else 0)) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            pass
        return r.ru_utime + r.ru_stime, busy, time.monotonic()

    def lap(self, name: str) -> None:
        now = self._now()
        self.rows.append((name, now[0] - self._last[0], now[1] - self._last[1], now[2] - self._last[2]))
        self._last = now

    def report(self) -> str:
        total = [sum(r[i] for r in self.rows) for i in (1, 2, 3)]
        parts = ", ".join(f"{name} {cpu:.0f} s" for name, cpu, _, _ in self.rows)
        return (f"dev.py: CPU {total[0]:.0f} s ({total[0] / 60:.1f} min; {parts}); the machine busy {total[1]:.0f} s;"
                f" {total[2] / 60:.1f} min of wall time on {os.cpu_count()} cores")


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("demo", "test", "setup"):
        print(__doc__.strip())
        return 2
    clock = CpuClock()
    setup()
    clock.lap("set-up")
    cmd, rest = argv[0], argv[1:]
    if cmd == "setup":
        print(f"dev.py: ready; run {BIN / 'rig'} --help")
        return 0
    if cmd == "demo":
        return subprocess.call([str(BIN / "rig"), "demo", *rest], env=child_env())
    fp_only = "--fp-paths" in rest
    rest = [a for a in rest if a != "--fp-paths"]
    whole = not rest or rest == ["--quick"]  # a tier, not a selection: worth compiling the kernels first
    # the whole suite writes where its CPU went, by test file (tests/cpu_table.py; docs/testing.md has the table)
    runs = [] if fp_only else [("pytest", {}, rest or [f"--cpu-table={VENV / 'suite-cpu.md'}"])]
    if fp_only or not rest:  # the whole suite's numeric tests again, on other floating-point paths
        other = other_fp_env(BIN / "python")
        # in one process, which compiles for the generic CPU only the kernels these tests use: two workers and the
        # warm-up compiled all of them and some twice (45 -> 30 s of CPU, measured side by side on a busy machine)
        runs.append(("numeric tests on other paths", other, ["-m", "numeric", "-n", "0", *rest]))
    code = 0
    for name, env, args in runs:
        if env:
            print(f"dev.py: {name}: " + " ".join(f"{k}='{v}'" for k, v in env.items()), flush=True)
        if whole and not env:  # numba's kernels compiled once here, not by every worker at once (tests/warm_kernels.py)
            subprocess.call([str(BIN / "python"), str(ROOT / "tests" / "warm_kernels.py")], cwd=ROOT,
                            stdout=subprocess.DEVNULL, env=child_env() | env)
            clock.lap("kernels")
        code = max(code, subprocess.call([str(BIN / "python"), "-m", "pytest", *args], cwd=ROOT, env=child_env() | env))
        clock.lap(name)
    if not rest and not fp_only:  # the whole suite: the benchmark's quick tier, printed beside the last recorded
        code = max(code, subprocess.call([str(BIN / "python"), "-m", "benchmarks.ci_tier"], cwd=ROOT, env=child_env()))
        clock.lap("benchmarks")
    print(clock.report(), flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
