"""The outputs' fault matrix (issue 52): every write, fsync, rename, unlink, linkat and renameat2 of rig export, rig fit
--table/--plot/--report, rig compare --report and rig export --sigma-map, killed (SIGKILL) or failed with ENOSPC by the
kernel through strace, with an old output in place. For each trial: is every output the old one, a whole new one or
absent (never a part), and what else is left in the folder, and after the next run.

    .venv/bin/python -m tests.output_fault_matrix                 # every command, ~10 min on 2 cores
    .venv/bin/python -m tests.output_fault_matrix "fit --table"   # one
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RIG = [sys.executable, "-c", "import sys; from rig.cli import main; sys.exit(main(sys.argv[1:]))"]
ENV = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "PYTHONPATH": str(ROOT)}
CALLS = ("write", "fsync", "rename", "unlink", "linkat", "renameat2")
FAULTS = ("signal=KILL", "error=ENOSPC")
#: command (a.h5 and b.h5 are the recordings) and the outputs it writes
COMMANDS = {
    "export": (["export", "a.h5", "-o", "m.json"], ["m.json"]),
    "fit --table": (["fit", "a.h5", "--table", "t.csv"], ["t.csv"]),
    "fit --plot": (["fit", "a.h5", "--plot", "p.png"], ["p.png"]),
    "fit --report": (["fit", "a.h5", "--report", "rep"], ["rep/fit.html", "rep/fit-sigma.png",
                                                          "rep/fit-measured-predicted.png"]),
    "compare --report": (["compare", "a.h5", "b.h5", "--report", "cmp"], ["cmp/compare.html", "cmp/compare-overlay.png"]),
    "export --sigma-map": (["export", "a.h5", "-o", "m.json", "--sigma-map", "1,2"],
                           ["m.json", "m.sigma-map.npy", "m.sigma-map.tif", "m.sigma-map.png"]),
}


def whole(name: str, content: bytes, reference: bytes) -> bool:
    """A whole new output (its timestamps may differ from `reference`, a clean run's)."""
    if name.endswith(".json"):
        try:
            return json.loads(content)["schema"] == "rig.noise-model/1"
        except (ValueError, KeyError):
            return False
    if name.endswith(".png"):
        return content.startswith(b"\x89PNG") and content.endswith(b"IEND\xaeB`\x82")
    if name.endswith(".html"):
        return content.rstrip().endswith(b"</html>")
    return len(content) == len(reference) if name.endswith((".npy", ".tif")) else content == reference


def folder(tmp: Path, recordings: tuple[Path, Path], outputs: list[str]) -> Path:
    shutil.copy(recordings[0], tmp / "a.h5")
    shutil.copy(recordings[1], tmp / "b.h5")
    for o in outputs:
        (tmp / o).parent.mkdir(exist_ok=True)
        (tmp / o).write_bytes(b"OLD")
    return tmp


def others(d: Path, outputs: list[str]) -> list[str]:
    return sorted(str(p.relative_to(d)) for p in d.rglob("*")
                  if p.is_file() and p.name not in ("a.h5", "b.h5") and str(p.relative_to(d)) not in outputs)


def strace(args: list[str], cwd: Path, extra: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(["strace", "-f", *extra, *RIG, *args], cwd=cwd, capture_output=True, text=True, env=ENV)


def sweep(name: str, recordings: tuple[Path, Path]) -> tuple[int, list[str]]:
    args, outputs = COMMANDS[name]
    with tempfile.TemporaryDirectory() as t:
        d = folder(Path(t), recordings, outputs)
        strace(args, d, ["-o", "/dev/null"])
        reference = {o: (d / o).read_bytes() for o in outputs}
    trials, findings = 0, []
    for call in CALLS:
        with tempfile.TemporaryDirectory() as t:
            d = folder(Path(t), recordings, outputs)
            strace(args, d, ["-o", str(d / ".log"), "-e", f"trace={call}"])
            n_calls = sum(f"{call}(" in line for line in (d / ".log").read_text().splitlines())
        for n in range(1, n_calls + 1):
            for fault in FAULTS:
                with tempfile.TemporaryDirectory() as t:
                    d = folder(Path(t), recordings, outputs)
                    strace(args, d, ["-o", "/dev/null", "-e", f"trace={call}", "-e", f"inject={call}:{fault}:when={n}"])
                    trials += 1
                    for o in outputs:
                        c = (d / o).read_bytes() if (d / o).exists() else None
                        if c not in (b"OLD", None) and not whole(o, c, reference[o]):
                            findings.append(f"{call} #{n} {fault}: {o} is a part ({len(c)} bytes)")
                    left = others(d, outputs)
                    if left:
                        strace(args, d, ["-o", "/dev/null"])  # the next run of the command
                        findings.append(f"{call} #{n} {fault}: left {left}; after the next run: {others(d, outputs)}")
    return trials, findings


def main() -> None:
    from rig.cli import main as rig

    wanted = sys.argv[1:] or list(COMMANDS)
    with tempfile.TemporaryDirectory() as t:
        recs = (Path(t) / "a.h5", Path(t) / "b.h5")
        for seed, path in zip((1, 2), recs):
            rig(["run", "--protocol", "perpendicular", "--camera", f"fake:width=32,height=18,seed={seed}",
                 "--frames", "10", "-o", str(path), "-q"])
        for name in wanted:
            trials, findings = sweep(name, recs)
            print(f"| {name} | {trials} | {'; '.join(findings) or 'old or whole, nothing left'} |", flush=True)


if __name__ == "__main__":
    main()
