"""The fault matrix of docs/reliability.md: every write system call of a small `rig run` and `rig import`, failed
with ENOSPC or killed (SIGKILL) by the kernel through strace, and what came of it.

For each (command, system call, fault, index N): the exit status, whether stderr was one line without a traceback,
what was left in the folder, and whether the next command (`--resume` for a run whose run.h5 exists, else the same
command again) finished with exactly the recording in the folder. Outcomes are grouped over N.

    .venv/bin/python -m tests.fault_matrix            # the whole sweep, ~6 min on 2 cores; prints a Markdown table
    .venv/bin/python -m tests.fault_matrix --every 10  # every 10th index (quick look)
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import tempfile
from collections import defaultdict
from pathlib import Path

from test_enospc_injection import IMPORT, RIG, RUN  # the commands the ENOSPC and kill tests fault, the same here

#: no bytecode written by the traced command: the N-th write is then its own, whatever Python's cache holds
ENV = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
COMMANDS = {"rig run": (RUN, "run.h5"), "rig import": (IMPORT, "d.h5")}
FAULTS = {"ENOSPC": "error=ENOSPC", "SIGKILL": "signal=KILL"}


def count(args: list[str], call: str) -> int:
    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "log"
        subprocess.run(["strace", "--seccomp-bpf", "-f", "-o", str(log), "-e", f"trace={call}", *RIG, *args], cwd=d, check=True,
                       capture_output=True, env=ENV)
        return sum(f"{call}(" in line for line in log.read_text().splitlines())


def _complete(path: Path) -> bool:
    from protocols.recording import Recording

    with Recording(path) as rec:
        return "ended_utc" in rec.attrs and not rec.skipped


def trial(args: list[str], out: str, call: str, fault: str, n: int) -> tuple[str, str]:
    """(what the faulted command did, what the next command did)."""
    with tempfile.TemporaryDirectory() as d:
        cwd = Path(d)
        fast = [] if fault == "SIGKILL" else ["--seccomp-bpf"]  # strace 6.1 with --seccomp-bpf and signal=KILL let the command finish
        p = subprocess.run(["strace", *fast, "-f", "-o", "/dev/null", "-e", f"trace={call}", "-e",
                            f"inject={call}:{FAULTS[fault]}:when={n}", *RIG, *args], cwd=cwd, capture_output=True, text=True,
                           env=ENV)
        lines = p.stderr.strip().splitlines()
        if p.returncode == 0:
            first = "finished (the fault hit no write that mattered)"
        elif fault == "SIGKILL":
            first = "killed"
        elif len(lines) == 1 and "Traceback" not in p.stderr:
            first = f"exit {p.returncode}, one line"
        else:
            first = f"exit {p.returncode}, {len(lines)} lines" + (", traceback" if "Traceback" in p.stderr else "")
        left = sorted(x.name for x in cwd.iterdir())
        if left == [out] and _complete(cwd / out):  # the fault hit a line to stdout after the output was whole
            return first, f"nothing to redo: {out} whole"
        again = [*args, "--resume"] if args is RUN and (cwd / out).exists() else args
        q = subprocess.run([*RIG, *again], cwd=cwd, capture_output=True, text=True)
        after = sorted(x.name for x in cwd.iterdir())
        how = "--resume" if "--resume" in again else "again"
        second = f"{how}: finished, only {out}" if q.returncode == 0 and after == [out] else \
            f"{how}: exit {q.returncode}, left {after}"
        return first, second


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every", type=int, default=1, help="every K-th index only")
    a = ap.parse_args()
    if not shutil.which("strace"):
        raise SystemExit("strace is not installed (apt-get install strace)")
    print("| command | system call | fault | indices | outcome | next command |")
    print("|---|---|---|---|---|---|")
    for name, (args, out) in COMMANDS.items():
        for call in ("write", "pwrite64"):
            total = count(args, call)
            for fault in FAULTS:
                groups: dict[tuple[str, str], list[int]] = defaultdict(list)
                for n in range(1, total + 1, a.every):
                    groups[trial(args, out, call, fault, n)].append(n)
                for (first, second), ns in sorted(groups.items(), key=lambda kv: kv[1][0]):
                    span = f"{len(ns)} of {len(range(1, total + 1, a.every))} ({ns[0]}-{ns[-1]})"
                    print(f"| {name} | {call} (of {total}) | {fault} | {span} | {first} | {second} |", flush=True)


if __name__ == "__main__":
    main()
