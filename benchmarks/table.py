"""python -m benchmarks.table [--json FILE] [--doc FILE] [--check]

Writes the benchmark's figures (the JSON `python -m benchmarks --json FILE` writes) into docs/performance.md, between
the lines `<!-- table: benchmark-results.json -->` and `<!-- end table -->`: the machine, the settings and the table
the benchmark printed. The docs quote no figure of their own; tests/test_docs_figures.py fails when the block and the
file differ. `--check` only says whether they do (exit 1).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from dataclasses import fields
from pathlib import Path

from .figures import Figure, table

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmark-results.json"
DOC = ROOT / "docs" / "performance.md"
BEGIN = "<!-- table: benchmark-results.json -->"
END = "<!-- end table -->"


def figures_of(doc: dict) -> list[Figure]:
    """The JSON's figures as `Figure`s (null, the JSON's NaN, back to NaN)."""
    names = {f.name for f in fields(Figure)}
    out = []
    for row in doc["figures"]:
        kept = {k: v for k, v in row.items() if k in names}
        kept.update({k: float("nan") for k in ("ours", "baseline") if kept.get(k) is None})
        out.append(Figure(**kept))
    return out


def provenance_line(doc: dict) -> str:
    """Where, when and how the figures were measured, in one line (what the file does not record is said so)."""
    m = doc.get("machine", {})
    machine = ", ".join(x for x in (
        m.get("cpu") or "an unnamed CPU", f"{m['cores']} cores" if m.get("cores") else "",
        f"Python {m['python']}" if m.get("python") else "",
        *(f"{lib} {m[lib]}" for lib in ("numpy", "numba") if m.get(lib)), m.get("platform", "")) if x)
    load = m.get("load_average")
    s = doc.get("settings", {})
    size = s.get("size", {})
    how = "`python -m benchmarks" + (" --quick" if s.get("quick") else "")
    if s.get("only"):
        how += " --only " + " ".join(s["only"])
    if s.get("repeat", 1) > 1:
        how += f" --repeat {s['repeat']}"
    how += "`"
    sweep = (f"a {size['width']}x{size['height']} sweep of {size['frames']} frames a stop"
             if size else "the sweep's size not recorded")
    when = doc.get("measured", {})
    at = (f"at {when['commit']}, {when['utc']} UTC" if when.get("commit") else
          f"{when['utc']} UTC" if when.get("utc") else "commit and date not recorded in the file")
    load_words = f" (load average {', '.join(f'{x:g}' for x in load)} at the end)" if load else ""
    return f"Measured on {machine}{load_words}; {how}, {sweep}; {at}."


def block(doc: dict) -> str:
    """The generated block, markers included."""
    return f"{BEGIN}\n{provenance_line(doc)}\n\n{table(figures_of(doc))}\n{END}"


def rewrite(text: str, doc: dict) -> str:
    """`text` with its block replaced by the one made from `doc`."""
    pattern = re.compile(re.escape(BEGIN) + r".*?" + re.escape(END), re.S)
    if not pattern.search(text):
        raise ValueError(f"no block between {BEGIN!r} and {END!r}")
    return pattern.sub(lambda _: block(doc), text, count=1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.table", description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, default=RESULTS, help="the benchmark's figures (default: %(default)s)")
    ap.add_argument("--doc", type=Path, default=DOC, help="the page whose block is rewritten (default: %(default)s)")
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 if the block differs")
    args = ap.parse_args(argv)
    text = args.doc.read_text()
    new = rewrite(text, json.loads(args.json.read_text()))
    if args.check:
        if new != text:
            print(f"{args.doc}: the table differs from {args.json}; run python -m benchmarks.table", file=sys.stderr)
            return 1
        return 0
    if new != text:
        args.doc.write_text(new)
        print(f"{args.doc}: table rewritten from {args.json}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
