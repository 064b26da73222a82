"""The outputs' fault matrix (issue 52): every write, fsync, rename, unlink, linkat and renameat2 of rig export, rig fit
--table/--plot/--report, rig compare --report and rig export --sigma-map, killed (SIGKILL) or failed with ENOSPC by the
kernel through strace, with an old output in place. For each trial: is every output the old one, a whole new one or
absent (never a part), and what else is left in the folder, and after the next run.

    .venv/bin/python -m tests.output_fault_matrix                  # every command: the table of docs/reliability.md
    .venv/bin/python -m tests.output_fault_matrix "fit --table"    # one
    .venv/bin/python -m tests.output_fault_matrix --json           # the trials and findings, as JSON
    .venv/bin/python -m tests.output_fault_matrix --calls write,fsync,rename,unlink ...   # only these calls

One process imports rig once and forks a child for each trial (tests/forked_rig.py); strace attaches to the child
(`strace -p`) before it starts the command, so the N-th traced call is the command's own and each trial costs the
command, not a new interpreter's ~1.5 s of imports.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
from pathlib import Path

from tests import forked_rig
from tests.forked_rig import run

forked_rig.for_forking()  # before numpy is imported

CALLS = ("write", "fsync", "rename", "unlink", "linkat", "renameat2")
FAULTS = ("signal=KILL", "error=ENOSPC")
#: command (a.h5 and b.h5 are the recordings) and the outputs it writes
COMMANDS = {
    "export": (["export", "a.h5", "-o", "m.json"], ["m.json"]),
    "fit --table": (["fit", "a.h5", "--table", "t.csv"], ["t.csv"]),
    "fit --plot": (["fit", "a.h5", "--plot", "p.png"], ["p.png"]),
    "fit --report": (["fit", "a.h5", "--report", "rep"], ["rep/fit.html", "rep/fit-sigma.png",
                                                          "rep/fit-measured-predicted.png"]),
    "compare --report": (["compare", "a.h5", "b.h5", "--report", "cmp", "--jobs", "1"],  # no pool: its own calls
                         ["cmp/compare.html", "cmp/compare-overlay.png"]),
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
                  if p.is_file() and p.name not in ("a.h5", "b.h5", ".log") and str(p.relative_to(d)) not in outputs)


def warm(args: list[str], recordings: tuple[Path, Path], outputs: list[str]) -> None:
    """The command once in this process (`forked_rig.warm`), in a folder of its own."""
    with tempfile.TemporaryDirectory() as t:
        forked_rig.warm(args, folder(Path(t), recordings, outputs))


def sweep(name: str, recordings: tuple[Path, Path], calls: tuple[str, ...] = CALLS) -> dict:
    """Every traced call of one command, killed and failed; the trials by call and what went wrong in any."""
    args, outputs = COMMANDS[name]
    warm(args, recordings, outputs)
    with tempfile.TemporaryDirectory() as t:
        d = folder(Path(t), recordings, outputs)
        run(args, d, ["-o", str(d / ".log"), "-e", "trace=" + ",".join(calls)])
        log = (d / ".log").read_text().splitlines()
        reference = {o: (d / o).read_bytes() for o in outputs}
        clean_left = others(d, outputs)
    counts = forked_rig.call_counts(log, calls)
    findings = [f"a clean run left {clean_left}"] if clean_left else []
    findings += [f"a clean run did not write {o}" for o in outputs if reference[o] == b"OLD"]
    trials = 0
    for call in calls:
        for n in range(1, counts[call] + 1):
            for fault in FAULTS:
                with tempfile.TemporaryDirectory() as t:
                    d = folder(Path(t), recordings, outputs)
                    run(args, d, ["-o", "/dev/null", "-e", f"trace={call}", "-e", f"inject={call}:{fault}:when={n}"])
                    trials += 1
                    for o in outputs:
                        c = (d / o).read_bytes() if (d / o).exists() else None
                        if c not in (b"OLD", None) and not whole(o, c, reference[o]):
                            findings.append(f"{call} #{n} {fault}: {o} is a part ({len(c)} bytes)")
                    left = others(d, outputs)
                    if left:
                        kill_at_rename = fault == "signal=KILL" and call == "rename"
                        run(args, d, None)  # the next run of the command
                        after = others(d, outputs)
                        if after or not kill_at_rename:
                            findings.append(f"{call} #{n} {fault}: left {left}; after the next run: {after}")
    return {"command": name, "calls": counts, "trials": trials, "findings": findings}


def recordings(where: Path) -> tuple[Path, Path]:
    """Two small simulated perpendicular runs (32x18 px, 5 stops of 6 frames, seeds 1 and 2)."""
    from rig.cli import main as rig

    recs = (where / "a.h5", where / "b.h5")
    for seed, path in zip((1, 2), recs):
        rig(["run", "--protocol", "perpendicular", "--camera", f"fake:width=32,height=18,seed={seed}",
             "--stops", "0.5:2.5:0.5", "--frames", "6", "-o", str(path), "-q"])
    return recs


def _cpu() -> float:
    """CPU of this process and of its children (the forked commands, strace) so far, in s."""
    import resource

    return sum(getattr(resource.getrusage(w), f) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
               for f in ("ru_utime", "ru_stime"))


def main(argv: list[str]) -> int:
    as_json = "--json" in argv
    calls = CALLS
    if "--calls" in argv:
        i = argv.index("--calls")
        calls = tuple(argv[i + 1].split(","))
        argv = argv[:i] + argv[i + 2:]
    wanted = [a for a in argv if a != "--json"] or list(COMMANDS)
    import matplotlib

    matplotlib.use("Agg")
    forked_rig.fonts_in_memory()
    with tempfile.TemporaryDirectory() as t:
        recs = recordings(Path(t))
        rows = []
        for name in wanted:
            before = _cpu()
            rows.append(sweep(name, recs, calls) | {"cpu_s": 0.0})
            rows[-1]["cpu_s"] = round(_cpu() - before, 1)
            if not as_json:
                r = rows[-1]
                print(f"| {name} | {r['trials']} | {'; '.join(r['findings']) or 'old or whole, nothing left'} |"
                      f" ({r['cpu_s']} s of CPU)",
                      flush=True)
    if as_json:
        print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
