"""`rig check REC [REC ...] --spec spec.toml`: recordings judged against a specification (rig.check, docs/check.md).
Each recording is measured in a worker of the pool `rig compare` uses (or on its Dask cluster: rig.fleet.executors)."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace

from .options import at_least
from .usage import UsageError

EPILOG = ("Exit status: 0 every line of every recording passes; 1 a line fails; 2 bad input (a spec or a recording "
          "that cannot be read: one line on stderr); 3 no line fails, but one is not decided (its limit lies within "
          "2 standard errors of the measured value, or nothing measures it).")


def register(sub: argparse._SubParsersAction) -> None:
    from .recordings import cluster_options

    p = sub.add_parser("check", parents=[cluster_options()], epilog=EPILOG,
                       help="pass or fail recordings against a specification (sigma at a range, fill, accuracy)")
    p.add_argument("recording", nargs="+", help="recordings, or folders of them (a fleet)")
    p.add_argument("--spec", required=True, metavar="SPEC.toml", help="the limits, one table a line (docs/check.md)")
    p.add_argument("--json", action="store_true", help="print the verdicts as rig.check/1 JSON (docs/check.md)")
    p.add_argument("--jobs", type=at_least(1, "processes"), default=os.cpu_count() or 1,
                   help="recordings measured at once (default: one per core)")
    p.set_defaults(func=cmd_check)


def cmd_check(args: argparse.Namespace) -> int:
    from ..check import SpecError, document, evaluate, exit_status, measure, read_spec, render
    from ..fleet.executors import run_each
    from ..fleet.many import portable
    from ..models.fitting.progress import ProgressCounter
    from ..reports.result_json import dumps
    from .recordings import cluster_timeout, expand
    from .shared import progress_line

    try:
        spec = read_spec(args.spec)  # before any recording is read
    except SpecError as e:
        raise UsageError(str(e)) from None
    paths = expand(args.recording)
    given = {str(portable(p)): p for p in paths}
    timeout_s = cluster_timeout(args)
    figures = {}
    with progress_line(args, "rig check") as progress:
        counter = ProgressCounter(progress, len(paths))
        try:
            for f in run_each(measure, list(given), jobs=args.jobs, scheduler=args.scheduler, timeout_s=timeout_s):
                figures[given[f.path]] = f
                counter.step(f"measured {len(figures)} of {len(paths)} recordings")
        except ValueError as e:  # the engine's: a --scheduler that does not answer
            raise UsageError(str(e)) from None
        counter.finish()
    verdicts = [evaluate(spec, replace(figures[p], path=p)) for p in paths]  # named as given
    status = exit_status(verdicts)
    for v in verdicts:  # the report names them too; stderr is where a CI log looks for what went wrong
        if v.error:
            print(f"rig: error: {v.error}", file=sys.stderr)
    print(dumps(document(spec, verdicts, status)) if args.json else render(spec, verdicts, status))
    return status

