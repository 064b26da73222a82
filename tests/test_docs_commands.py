"""The commands the manual tells a user to type (tests/docs_commands.py extracts them from README.md and docs/*.md)
are commands rig takes: each `rig ...` parses with rig's own parser, with device strings and protocol options rig
accepts; each file one reads is in a clone or written by an earlier command of its document (or declared, with
where it comes from); and a few cheap ones run here as written. Running them all (minutes of CPU) is
`python -m tests.docs_commands --run`; tests/test_readme.py runs the README's passive and tilted lines and checks
their exponents."""

from __future__ import annotations

import argparse
import fnmatch
import functools
import io
import re
import shutil
from contextlib import redirect_stderr
from pathlib import Path

from cli_in_process import rig_in_process
from docs_commands import (DEMO, DEMO_WRITES, EXPECTED, NOT_RUN, OUTSIDE, ROOT, SUBCOMMANDS, Command, all_commands,
                           expected_status, rig_invocations, simple_commands)
from rig.cli import build_parser

COMMANDS = all_commands()
PARSER = build_parser()

#: what a synopsis's placeholders stand for, to parse it (docs/models.md: `rig diagnose REC.h5 [--model M]`)
PLACEHOLDERS = {"N": "3", "M": "active", "DIR": "out"}

#: the arguments of each command that name a file or folder it reads, and those that name one it writes
READS = {"run": ("experiment",), "import": ("folder",), "fit": ("recording", "effects"),
         "compare": ("recording", "effects"), "accuracy": ("recording", "effects"),
         "diagnose": ("recording", "effects"), "export": ("recording", "effects"),
         "repeatability": ("recording", "effects"), "check": ("recording", "spec"), "sigma-bag": ("model", "bag"),
         "tui": ("recording", "experiment")}
WRITES = {"run": ("output",), "simulate": ("output",), "import": ("output",), "fit": ("plot", "table", "report"),
          "compare": ("plot", "report"), "diagnose": ("out",), "export": ("out",), "repeatability": ("plot", "report"),
          "validate-diagnosis": ("json",), "paper-windows": ("out",), "demo": ("out",), "sigma-bag": ("out",)}


def concrete(command: Command) -> Command:
    """A synopsis made a command to parse: `a|b` -> a, `[--x X]` -> --x X, `... --json` -> REC.h5 --json, a
    trailing `...` dropped, placeholders given a value (PLACEHOLDERS); a command as it is."""
    if command.kind != "synopsis":
        return command
    text = re.sub(r"(\w[\w-]*)(\|[\w-]+)+", r"\1", command.text)
    text = re.sub(r"\[([^\]]*)\]", r"\1", text)
    text = re.sub(r"\.\.\.(?=\s+\S)", "REC.h5", text)
    text = re.sub(r"\s*(?<!')\.\.\.$", "", text)
    text = " ".join(PLACEHOLDERS.get(w, w) for w in text.split(" "))
    return Command(command.doc, command.line, text)


def parse(argv: list[str]) -> tuple[argparse.Namespace | None, str]:
    """rig's parser on `argv`: the arguments, or None and argparse's message."""
    err = io.StringIO()
    with redirect_stderr(err):
        try:
            return PARSER.parse_args(argv), ""
        except SystemExit:
            return None, err.getvalue().strip().splitlines()[-1]


@functools.cache
def device_problem(camera: str, stage: str) -> str:
    """What rig says of a camera and stage string before it opens them ('' if nothing): the devices built, unopened."""
    from drivers.errors import DeviceError
    from rig.devices import open_devices

    try:
        open_devices(camera, stage)
    except DeviceError as e:
        return str(e)
    return ""


def problems_of(args: argparse.Namespace) -> list[str]:
    """What rig refuses after parsing and before it opens anything: device strings, a protocol's options."""
    from rig.cli.acquire import protocol_options
    from rig.cli.usage import UsageError
    from protocols.catalogue import protocol_spec

    camera = getattr(args, "camera", None) or getattr(args, "check", None) or "fake:"
    found = list(filter(None, [device_problem(camera, getattr(args, "stage", None) or "fake:")]))
    if args.command == "run" and args.protocol:
        try:
            protocol_options(args, protocol_spec(args.protocol))
        except UsageError as e:
            found.append(str(e))
    return found


def test_the_extraction_finds_what_a_reader_types():
    """The extraction sees what a reader sees: the commands of each kind of block, a loop as one command, a session's
    commands without their output, set-up apart, every document with a command block."""
    docs = {c.doc for c in COMMANDS}
    assert {"README.md", "docs/calibration-week.md", "docs/import.md", "docs/tui.md", "docs/testing.md"} <= docs
    assert documented("README.md", "source .venv/bin/activate").kind == "setup"
    loop = next(c for c in COMMANDS if c.doc == "docs/calibration-week.md" and "warm$s.h5" in c.text)
    assert loop.text.startswith("for s in 1 2 3 4 5; do") and loop.text.endswith("done") and "\\" not in loop.text
    assert [a[-3:] for a in rig_invocations(loop)] == [["-o", f"week/warm{s}.h5", "-q"] for s in range(1, 6)]
    assert not any(c.text.startswith(("importing", "note:", "[")) for c in COMMANDS)  # a session's output
    assert documented("docs/models.md", "rig diagnose REC.h5 [--model M] [--out DIR]").kind == "synopsis"
    assert documented("docs/models.md", "rig paper-windows").kind == "command"
    assert len([c for c in COMMANDS if c.kind == "command"]) >= 90
    subparsers = next(a for a in PARSER._actions if isinstance(a, argparse._SubParsersAction))
    assert set(SUBCOMMANDS) == set(subparsers.choices)  # what tells a command from prose starting "rig "


def test_every_documented_rig_command_parses():
    """Each `rig ...` the docs give, synopses filled in, is taken by rig's parser, and its device strings and
    protocol options by what checks them before anything opens: a misspelt flag, a removed subcommand, a value of
    the wrong type or a device option that does not exist fails here, naming the document and line."""
    failures, parsed = [], 0
    for c in COMMANDS:
        for argv in rig_invocations(concrete(c)):
            args, message = parse(argv)
            parsed += 1
            if args is None:
                failures.append(f"{c.where}: rig {' '.join(argv)}: {message}")
            else:
                failures += [f"{c.where}: rig {' '.join(argv)}: {p}" for p in problems_of(args)]
    assert not failures, "\n".join(failures)
    assert parsed >= 80


def test_the_check_fails_on_a_wrong_command():
    """What the test above would say of a misspelt flag, a subcommand that does not exist, a value of the wrong type,
    a device option that does not exist."""
    for argv in (["fit", "run.h5", "--zmin", "1"], ["fitt", "run.h5"], ["paper-windows", "--frames", "many"]):
        args, message = parse(argv)
        assert args is None and message.startswith("rig") and "error:" in message, (argv, message)
    args, _ = parse(["run", "--protocol", "tilted", "--tilt-deg", "31", "--camera", "fake:widht=212", "-o", "t.h5"])
    assert problems_of(args) == [problems_of(args)[0]] and "did you mean width?" in problems_of(args)[0]
    args, _ = parse(["run", "--protocol", "perpendicular", "--tilt-deg", "31", "-o", "t.h5"])
    assert any("--tilt-deg is not a parameter of perpendicular" in p for p in problems_of(args))


def files_of(argv: list[str]) -> tuple[list[str], list[str]]:
    """The files and folders `rig argv` reads and writes, as written (the experiment file's output, for rig run
    FILE.toml without -o, relative to the clone, as rig resolves it)."""
    from protocols.experiment_file import load_experiment

    args, _ = parse(argv)
    if args is None:  # test_every_documented_rig_command_parses says so
        return [], []

    def values(dests: tuple[str, ...]) -> list[str]:
        out = []
        for d in dests:
            v = getattr(args, d, None)
            out += [str(x) for x in (v if isinstance(v, list) else [v]) if x]
        return out

    reads, writes = values(READS.get(args.command, ())), values(WRITES.get(args.command, ()))
    if args.command == "run" and args.experiment and not args.output and (ROOT / args.experiment).is_file():
        writes.append(str(load_experiment(ROOT / args.experiment).output.relative_to(ROOT)))
    return reads, writes


def is_there(path: str, written: set[str], outside: dict[str, str]) -> bool:
    """`path` is in a clone, written earlier (or a folder of something written, or a glob matching it), or declared."""
    bare = path.rstrip("/")
    return (path in outside or bare in outside or (not Path(path).is_absolute() and (ROOT / path).exists())
            or any(bare == w or w.startswith(bare + "/") or fnmatch.fnmatch(w, bare) for w in written))


def test_every_file_a_command_reads_is_in_a_clone_or_made_by_an_earlier_command():
    """Follow each document in order, as its reader does: what a command reads must be in a fresh clone, or written
    by a command above it in the same document (`python3 dev.py demo` writes DEMO_WRITES), or declared in OUTSIDE
    with where it comes from; and every declaration is of a file the document reads."""
    from rig.simulation.demo import MODES

    assert {f"rig-output/perpendicular-{mode}.h5" for mode, *_ in MODES} <= set(DEMO_WRITES)  # the demo's recordings
    failures, used = [], set()
    for doc in dict.fromkeys(c.doc for c in COMMANDS):
        written: set[str] = set()
        outside = OUTSIDE.get(doc, {})
        for c in (c for c in COMMANDS if c.doc == doc and c.kind == "command"):
            for words, redirected in simple_commands(c.text):
                written.update(redirected)
                if words[0] == "mkdir":
                    written.update(w for w in words[1:] if not w.startswith("-"))
                if words[:3] == ["python3", "dev.py", "demo"]:
                    written.update(DEMO_WRITES)
                if words[0] != "rig":
                    continue
                reads, writes = files_of(words[1:])
                for path in reads:
                    if not is_there(path, written, outside):
                        failures.append(f"{c.where}: {c.text}: reads {path}, which nothing above writes")
                    used.update((doc, p) for p in (path, path.rstrip("/")) if p in outside)
                written.update(w.rstrip("/") for w in writes)
    assert not failures, "\n".join(failures)
    declared = {(doc, path) for doc, paths in OUTSIDE.items() for path in paths}
    assert declared <= used, f"declared but read by no command: {sorted(declared - used)}"


def test_the_runs_declarations_name_commands_the_documents_have():
    """NOT_RUN and EXPECTED (what `--run` leaves out, and the exit statuses that are right without hardware) each
    match a documented command, so none outlives the command it was written for."""
    texts = [c.text for c in COMMANDS if c.kind == "command"]
    for pattern, *_ in (*NOT_RUN, *EXPECTED):
        assert any(re.search(pattern, t) for t in texts), pattern
    assert all(v == DEMO or "your" in v for paths in OUTSIDE.values() for v in paths.values())


def documented(doc: str, text: str) -> Command:
    """The command of `doc` written `text` (the first, if several)."""
    return next(c for c in COMMANDS if c.doc == doc and c.text == text)


def run_as_written(command: Command) -> list:
    """Each `rig` invocation of `command`, in this process (tests/cli_in_process.py), its words as written."""
    return [rig_in_process(*argv) for argv in rig_invocations(command)]


def test_rig_devices_runs_as_written():
    """README's and hardware.md's `rig devices` on a machine with no camera: status 0, and it says what to try."""
    for doc in ("README.md", "docs/hardware.md"):
        (r,) = run_as_written(documented(doc, "rig devices"))
        assert r.returncode == 0, (doc, r.stderr)
        assert "fake:" in r.stdout + r.stderr, r.stdout  # nothing attached: the simulated rig is offered


def test_checking_a_camera_that_is_not_there_is_one_line():
    """hardware.md's `rig devices --check realsense:` without one: the status EXPECTED says, one line naming it."""
    c = documented("docs/hardware.md", "rig devices --check realsense:")
    (r,) = run_as_written(c)
    assert r.returncode == expected_status(c)[0] == 2, r
    assert len(r.stderr.strip().splitlines()) == 1 and "realsense" in r.stderr.lower(), r.stderr
    assert "Traceback" not in r.stderr


def test_the_worked_example_of_a_real_bag_runs_as_written_and_prints_what_the_page_shows(tmp_path, monkeypatch):
    """import.md's worked example: its two commands as written in a clone (the bag where the page says it is), and
    the lines the page shows of their output are what they print (but the seconds the import took)."""
    text = (ROOT / "docs" / "import.md").read_text()
    session = re.search(r"### Worked example: a real D435.*?```sh\n(.*?)```", text, flags=re.S).group(1)
    commands = [c for c in COMMANDS if c.doc == "docs/import.md" and c.text in
                [line[2:] for line in session.splitlines() if line.startswith("$ ")]]
    assert [c.text.split()[:2] for c in commands] == [["rig", "import"], ["rig", "fit"]]
    bag = rig_invocations(commands[0])[0][1]
    (tmp_path / bag).parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(ROOT / bag, tmp_path / bag)
    monkeypatch.chdir(tmp_path)
    printed = ""
    for c in commands:
        (r,) = run_as_written(c)
        assert r.returncode == expected_status(c)[0], (c.where, r)
        printed += r.stdout + r.stderr
    shown = [line for line in session.splitlines() if not line.startswith("$ ") and "..." not in line]
    shown = [re.sub(r"\(\s*[0-9.]+ s\)$", "", line).rstrip() for line in shown]
    missing = [line for line in shown if line not in printed]
    assert not missing, f"import.md shows lines its commands do not print:\n{missing}\nthey print:\n{printed}"
