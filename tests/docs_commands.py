"""The shell commands the manual tells a user to type (README.md and docs/*.md), each with its document and line.

  .venv/bin/python -m tests.docs_commands          list them
  .venv/bin/python -m tests.docs_commands --run    run each document's commands in order, as written (minutes of
                                                   CPU: not part of the suite; tests/test_docs_commands.py is)

A command is a line of a ```sh / ```bash / ```console block (only its `$ ` lines when the block shows a session with
its output), or a line starting `rig ` or `python3 dev.py` in another block or in the text; `\\` continues a line, a
`for ... done` loop is one command, `# ...` is a comment. Set-up (`source .venv/bin/activate`, `sudo apt-get`,
`pip install`) is listed but not run, and a synopsis (`rig fit REC.h5 [--model M]`, `...`) is listed but not run.

`--run` runs each document in a scratch folder of its own holding the repo's tracked files (a fresh clone, with the
repo's `.venv` linked in), every command through bash with `.venv/bin` first on PATH, and prints a table: where,
command, exit status, seconds and CPU, and the first error line. `NOT_RUN` says which commands it leaves out and why;
`OUTSIDE` which files a document reads that none of its own commands writes; `EXPECTED` the commands whose right
exit status on this machine is not 0. `rig tui` and `rig stage-sim` (`INTERACTIVE`) run on a pseudo-terminal for a
few seconds and are then stopped as a user would stop them.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md")))
SHELL_BLOCKS = ("sh", "bash", "console", "shell")
#: first words of set-up: preparing the environment, not using rig
SETUP = ("source", ".", "sudo", "apt-get", "pip", "pip3")
#: the subcommands of `rig`, for lines in the text that start with "rig " (prose, unless the next word is one)
SUBCOMMANDS = ("demo", "run", "simulate", "import", "fit", "compare", "accuracy", "diagnose", "export", "sigma-bag",
               "repeatability", "check", "devices", "tui", "paper-windows", "validate-diagnosis", "stage-sim")


@dataclass(frozen=True)
class Command:
    """One command as the manual writes it. text: continuation lines joined, the comment dropped (a loop keeps its
    lines); kind: "command", "setup" or "synopsis" (placeholders such as REC.h5, [--model M], fit|compare, ...)."""

    doc: str
    line: int
    text: str
    kind: str = "command"

    @property
    def where(self) -> str:
        return f"{self.doc}:{self.line}"


def strip_comment(line: str) -> str:
    """`line` without its shell comment: a `#` at the start of a word, outside quotes."""
    quote = ""
    for i, c in enumerate(line):
        if quote:
            quote = "" if c == quote else quote
        elif c in "'\"":
            quote = c
        elif c == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].rstrip()
    return line.rstrip()


PLACEHOLDER = re.compile(r"[A-Z][A-Z0-9_]*(\.[a-z0-9]+)?")


def kind_of(text: str) -> str:
    first = text.split(maxsplit=1)[0]
    if first in SETUP:
        return "setup"
    words = text.split()
    if "..." in text or any(w.startswith("[") for w in words) or re.search(r"\w\|\w", text) or \
            any(PLACEHOLDER.fullmatch(w) for w in words):
        return "synopsis"
    return "command"


def block_commands(doc: str, lines: list[tuple[int, str]]) -> list[Command]:
    """The commands of one shell block, `lines` its (line number, text) pairs."""
    if any(t.startswith("$ ") for _, t in lines):  # a session: commands after the prompt, the rest is their output
        return [Command(doc, n, strip_comment(t[2:]), kind_of(t[2:])) for n, t in lines if t.startswith("$ ")]
    logical: list[tuple[int, str]] = []
    pending: tuple[int, str] | None = None
    for n, t in lines:
        start, text = pending if pending else (n, "")
        text = f"{text} {t.strip()}" if text else t
        if text.rstrip().endswith("\\"):
            pending = (start, text.rstrip()[:-1].rstrip())
            continue
        pending = None
        text = strip_comment(text)
        if text.strip():
            logical.append((start, text))
    commands: list[Command] = []
    loop: list[tuple[int, str]] = []
    for n, t in logical:
        opens = re.match(r"\s*(for|while|until)\b", t) is not None
        if loop or opens:
            loop.append((n, t))
            if re.fullmatch(r"\s*done\s*", t):
                text = "\n".join(x for _, x in loop)
                commands.append(Command(doc, loop[0][0], text, kind_of(text)))
                loop = []
            continue
        commands.append(Command(doc, n, t.strip(), kind_of(t.strip())))
    return commands


def commands_of(doc: str) -> list[Command]:
    """Every command of one document (a path relative to the repo), in order."""
    found: list[Command] = []
    fence, block = None, []
    for n, line in enumerate((ROOT / doc).read_text().splitlines(), start=1):
        if line.startswith("```"):
            if fence is None:
                fence, block = line[3:].strip(), []
                continue
            if fence in SHELL_BLOCKS:
                found += block_commands(doc, block)
            fence = None
            continue
        if fence is None or fence not in SHELL_BLOCKS:
            words = line.split()
            said = len(words) > 1 and ((words[0] == "rig" and (words[1] in SUBCOMMANDS or words[1].startswith("-")))
                                       or words[:2] == ["python3", "dev.py"])
            if said and (fence is not None or not line.startswith(" ")):
                text = strip_comment(line).strip()
                found.append(Command(doc, n, text, kind_of(text)))
            continue
        block.append((n, line))
    return found


def all_commands(docs: tuple[str, ...] = DOCS) -> list[Command]:
    return [c for doc in docs for c in commands_of(doc)]


# ---- reading a command's words: the rig invocations in it, and the files its shell redirects to

def shell_words(text: str) -> list[str]:
    """The words of a shell line, with `|`, `&`, `;`, `>` ... as words of their own (shlex, as POSIX sh splits)."""
    lex = shlex.shlex(text, posix=True, punctuation_chars=True)
    lex.whitespace_split = True
    lex.commenters = ""
    return list(lex)


def simple_commands(text: str) -> list[tuple[list[str], list[str]]]:
    """The simple commands of `text` as (words, files written by `>`), a `for VAR in WORDS; do BODY done` loop
    unrolled with $VAR substituted; leading NAME=value assignments dropped."""
    loop = re.fullmatch(r"\s*for (\w+) in ([^;\n]+);\s*do\s*\n(.*)\n\s*done\s*", text, flags=re.S)
    if loop:
        var, values, body = loop.groups()
        return [c for v in values.split() for line in body.splitlines()
                for c in simple_commands(re.sub(rf"\$\{{?{var}\}}?", v, line))]
    out: list[tuple[list[str], list[str]]] = []
    words, written = [], []
    tokens = shell_words(text) + [";"]
    i = 0
    while i < len(tokens):
        w = tokens[i]
        if w in (">", ">>", "2>", "&>"):
            written.append(tokens[i + 1])
            i += 2
            continue
        if w and set(w) <= set("|&;()"):
            while words and re.fullmatch(r"[A-Za-z_]\w*=.*", words[0]):
                words.pop(0)
            if words:
                out.append((words, written))
            words, written = [], []
        else:
            words.append(w)
        i += 1
    return out


def rig_invocations(command: Command) -> list[list[str]]:
    """The argument lists of the `rig ...` commands in `command` (a pipeline's and a loop's included)."""
    return [words[1:] for words, _ in simple_commands(command.text) if words[0] == "rig"]


# ---- what --run leaves out, what documents read from outside, what exit status is right

#: `python3 dev.py demo` writes these (rig/simulation/demo.py: its MODES and its diagnosis loop)
DEMO_WRITES = ("rig-output/perpendicular-active.h5", "rig-output/perpendicular-passive.h5",
               "rig-output/perpendicular-active-unknown.h5", "rig-output/sigma-vs-range.png", "rig-output/diagnosis")
DEMO = "python3 dev.py demo writes it (the document says: after the demo)"

#: what a document's commands read that none of its earlier commands writes and a clone does not hold, and where it
#: comes from: the demo (--run copies its outputs in from one run of it), or the reader's own data or hardware
#: (--run leaves the commands that read it out)
OUTSIDE: dict[str, dict[str, str]] = {
    "README.md": {
        **{f"run{i}.h5": "your own runs of one camera (docs/calibration-week.md records five)" for i in range(1, 6)},
        "fleet/": "your own folder of recordings, on your Dask cluster",
        "wall-captures/": "your own folder of captured frames (docs/import.md)",
        "wall-1.5m.bag": "your own RealSense or ROS bag (docs/import.md)",
    },
    "docs/check.md": {"rig-output/": DEMO},
    "docs/tui.md": {"rig-output/perpendicular-active.h5": DEMO},
    "docs/import.md": {p: "your own bags or frames: the page shows the forms a command takes" for p in (
        "wall-1.50m.bag", "bags/", "ros2_bag/", "cams.mcap", "sim.mcap", "rec.mcap", "aligned.bag", "sweep.mcap",
        "wall-captures/", "wall-captures")},
    "docs/noise-model.md": {"run.bag": "your own bag of the camera the model describes"},
}

#: commands --run leaves out, by a pattern of their text, and why
NOT_RUN = (
    (r"^python3 dev\.py test", "the test suite itself (minutes of CPU)"),
    (r"^python -m benchmarks( --|$)", "the benchmark (minutes to 25 min of CPU; it writes benchmark-results.json)"),
    (r"^rig validate-diagnosis --seeds 10\b", "the whole blind test (18 min on 2 cores, docs/models.md)"),
    (r"^stress-ng", "loads both cores on purpose, for the real-time tests under load"),
    (r"^\.venv/bin/python -m pytest", "the real-time tests under load (the line above)"),
    (r"--scheduler tcp://scheduler:", "needs your Dask cluster (docs/calibration-week.md starts one on this machine)"),
)

#: commands whose right exit status on a machine without hardware is not 0, and why
EXPECTED = (
    (r"^rig devices --check realsense:", 2, "no RealSense attached: one line says so"),
)

#: run on a pseudo-terminal for INTERACTIVE_S, then stopped as its screen says (ctrl+q; Ctrl-C), with status 0
INTERACTIVE = ((r"^rig tui\b", b"\x11", "ctrl+q"), (r"^rig stage-sim\b", b"\x03", "ctrl+c"))
INTERACTIVE_S = 8.0
TIMEOUT_S = 1800.0


def not_run_reason(command: Command) -> str | None:
    if command.kind != "command":
        return command.kind
    for pattern, why in NOT_RUN:
        if re.search(pattern, command.text):
            return why
    outside = OUTSIDE.get(command.doc, {})
    for words, _ in simple_commands(command.text):
        for w in words:
            if w in outside and outside[w] != DEMO:
                return outside[w]
    return None


def expected_status(command: Command) -> tuple[int, str]:
    for pattern, status, why in EXPECTED:
        if re.search(pattern, command.text):
            return status, why
    return 0, ""


# ---- running a document's commands

@dataclass
class Outcome:
    command: Command
    status: int | None = None  # None: not run, or timed out
    seconds: float = 0.0
    cpu_s: float = 0.0
    note: str = ""  # why not run; the first error line; what an expected status means
    ok: bool | None = None  # None: not run


def fresh_clone(into: Path) -> Path:
    """The repo's tracked files copied into `into` (as a clone has them), its .venv linked."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout.decode()
    for name in filter(None, files.split("\0")):
        src, dst = ROOT / name, into / name
        if src.is_file():
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)
    (into / ".venv").symlink_to(ROOT / ".venv")
    return into


def first_error_line(out: str, err: str) -> str:
    lines = [ln.strip() for ln in (err + "\n" + out).splitlines() if ln.strip()]
    for ln in lines:
        if re.search(r"error|Traceback|not found|No such|refus", ln, flags=re.I):
            return ln
    return lines[-1] if lines else ""


def child_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_interactive(command: Command, cwd: Path, env: dict[str, str], keys: bytes) -> tuple[int | None, str]:
    """Run on a pseudo-terminal of 80x24; after INTERACTIVE_S, press `keys`; the exit status and what it printed."""
    import fcntl
    import pty
    import struct
    import termios

    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    proc = subprocess.Popen(["bash", "-o", "pipefail", "-c", command.text], cwd=cwd, env=env | {"TERM": "xterm-256color"},
                            stdin=slave, stdout=slave, stderr=slave, start_new_session=True)
    os.close(slave)
    seen = bytearray()

    def drain() -> None:
        while True:
            try:
                chunk = os.read(master, 65536)
            except OSError:
                return
            if not chunk:
                return
            seen.extend(chunk)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        proc.wait(INTERACTIVE_S)
        ended_early = True
    except subprocess.TimeoutExpired:
        ended_early = False
        os.write(master, keys)
    try:
        status = proc.wait(20)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        status = None
    reader.join(2)
    os.close(master)
    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]|\x1b[()][A-Z0-9]|\r", "", seen.decode(errors="replace"))
    if ended_early and status == 0:
        status, text = -1, f"ended by itself within {INTERACTIVE_S:g} s: {text}"
    return status, text


def demo_outputs(cache: dict[str, Path], env: dict[str, str]) -> Path:
    """A folder holding DEMO_WRITES: README.md's run's, or one `rig demo` run for this."""
    if "demo" not in cache:
        where = Path(tempfile.mkdtemp(prefix="rig-docs-demo-"))
        subprocess.run(["rig", "demo", "-q"], cwd=where, env=env, check=True, stdout=subprocess.DEVNULL)
        cache["demo"] = where
    return cache["demo"]


def run_document(doc: str, commands: list[Command], scratch: Path, cache: dict[str, Path],
                 report=print) -> list[Outcome]:
    """Run one document's commands in order in a fresh clone under `scratch`."""
    clone = fresh_clone(scratch / re.sub(r"\W", "-", doc))
    env = dict(os.environ)
    env["PATH"] = f"{ROOT / '.venv' / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(ROOT / ".venv")
    env.pop("PYTHONPATH", None)
    if any(v == DEMO for v in OUTSIDE.get(doc, {}).values()):
        made = demo_outputs(cache, env)
        (clone / "rig-output").mkdir()
        for path in DEMO_WRITES:  # only these: later commands of README.md write into rig-output/ too
            (shutil.copytree if (made / path).is_dir() else shutil.copy2)(made / path, clone / path)
    logs = scratch / "logs"
    logs.mkdir(exist_ok=True)
    outcomes, groups = [], []
    try:
        for c in commands:
            o = Outcome(c)
            outcomes.append(o)
            reason = not_run_reason(c)
            if reason is not None:
                o.note = f"not run: {reason}"
                report(row(o))
                continue
            want, why = expected_status(c)
            keys, pressed = next(((k, n) for p, k, n in INTERACTIVE if re.search(p, c.text)), (None, ""))
            t0, cpu0 = time.monotonic(), child_cpu()
            if keys is not None:
                o.status, text = run_interactive(c, clone, env, keys)
                out, err = "", text
                why = why or f"ran {INTERACTIVE_S:g} s, then {pressed}"
            else:
                out_path, err_path = logs / f"{clone.name}-{c.line}.out", logs / f"{clone.name}-{c.line}.err"
                with open(out_path, "wb") as fo, open(err_path, "wb") as fe:
                    # pipefail: `rig fit run.h5 --json | jq ...` fails when rig does, as its reader sees
                    proc = subprocess.Popen(["bash", "-o", "pipefail", "-c", c.text], cwd=clone, env=env,
                                            stdin=subprocess.DEVNULL, stdout=fo, stderr=fe, start_new_session=True)
                    groups.append(proc.pid)  # a background job (`dask scheduler &`) lives on in this group
                    try:
                        o.status = proc.wait(TIMEOUT_S)
                    except subprocess.TimeoutExpired:
                        os.killpg(proc.pid, signal.SIGKILL)
                        proc.wait()
                        o.note = f"timed out after {TIMEOUT_S:g} s"
                out, err = out_path.read_text(errors="replace"), err_path.read_text(errors="replace")
            o.seconds, o.cpu_s = time.monotonic() - t0, child_cpu() - cpu0
            o.ok = o.status == want
            if not o.ok:
                o.note = o.note or first_error_line(out, err)
            elif why:
                o.note = why
            report(row(o))
    finally:
        for pgid in groups:
            try:
                os.killpg(pgid, signal.SIGTERM)
            except ProcessLookupError:
                pass
    return outcomes


def row(o: Outcome) -> str:
    text = o.command.text.replace("\n", "; ")
    text = text if len(text) <= 70 else text[:67] + "..."
    verdict = "-" if o.ok is None else "ok" if o.ok else "FAIL"
    status = "" if o.status is None else str(o.status)
    timing = "" if o.ok is None else f"{o.seconds:6.1f} {o.cpu_s:6.1f}"
    return f"{verdict:<4} {o.command.where:<28} {text:<70} {status:>4} {timing:>13}  {o.note[:110]}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tests.docs_commands", description=__doc__.split("\n\n")[0])
    p.add_argument("--run", action="store_true", help="run them, each document in a scratch folder of its own")
    p.add_argument("docs", nargs="*", help="only these documents (default: README.md and docs/*.md)")
    p.add_argument("--keep", action="store_true", help="keep the scratch folders (their path is printed)")
    args = p.parse_args(argv)
    docs = tuple(args.docs) or DOCS
    commands = all_commands(docs)
    if not args.run:
        for c in commands:
            print(f"{c.where:<28} {c.kind:<8} {c.text}")
        print(f"{len(commands)} commands ({sum(c.kind == 'command' for c in commands)} to run) in {len(docs)} documents")
        return 0
    scratch = Path(tempfile.mkdtemp(prefix="rig-docs-commands-"))
    cache: dict[str, Path] = {}
    print(f"{'':<4} {'where':<28} {'command':<70} {'exit':>4} {'s':>6} {'cpu s':>6}  note", flush=True)
    outcomes: list[Outcome] = []
    try:
        for doc in docs:
            mine = [c for c in commands if c.doc == doc]
            if mine:
                outcomes += run_document(doc, mine, scratch, cache, report=lambda s: print(s, flush=True))
                if doc == "README.md" and (scratch / "README-md" / "rig-output").is_dir():
                    cache.setdefault("demo", scratch / "README-md")
    finally:
        if args.keep:
            print(f"scratch folders kept in {scratch}")
        else:
            shutil.rmtree(scratch, ignore_errors=True)
            if "demo" in cache and not str(cache["demo"]).startswith(str(scratch)):
                shutil.rmtree(cache["demo"], ignore_errors=True)
    ran = [o for o in outcomes if o.ok is not None]
    failed = [o for o in ran if not o.ok]
    print(f"{len(ran) - len(failed)} passed, {len(failed)} failed, {len(outcomes) - len(ran)} not run "
          f"(of {len(outcomes)}); CPU {sum(o.cpu_s for o in ran):.0f} s")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
