"""Commands over several recordings: `rig compare a.h5 b.h5 ...` (two cameras, projector on against off) and
`rig repeatability run1.h5 run2.h5 ...` (are the errors honest?). One model is fitted to each recording in a local
process pool, or on a Dask cluster (`--scheduler`, `rig.fleet.executors`); `rig.recordings.comparison` compares the fits."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .options import refuse_unwritable
from .usage import UsageError


def cluster_options() -> argparse.ArgumentParser:
    """--scheduler and --timeout: where the work over many recordings runs (fit --many, compare, repeatability)."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--scheduler", metavar="tcp://HOST:8786",
                   help="run the fits on this Dask cluster (default: $RIG_SCHEDULER, else a local process pool of --jobs)")
    p.add_argument("--timeout", type=float, metavar="SECONDS",
                   help="on a cluster, stop with an error after this long with no worker there: none joined, or the "
                        "last one was lost (default: 60)")
    return p


def cluster_timeout(args: argparse.Namespace) -> float | None:
    """--timeout, in seconds (None: the engine's default); one that is not a positive number is refused."""
    timeout_s = getattr(args, "timeout", None)
    if timeout_s is not None and not timeout_s > 0:
        raise UsageError(f"--timeout {timeout_s:g}: give a positive number of seconds to wait for a worker (default: 60)")
    return timeout_s


def register(sub: argparse._SubParsersAction) -> None:
    from .shared import shared_options

    p = sub.add_parser("repeatability", parents=[shared_options(several=True), cluster_options()],
                       help="repeated runs of one camera and setting: is the run-to-run scatter what the errors say?")
    p.add_argument("--model", help="the model to fit to every run (default: the paper's power law, as rig fit)")
    p.add_argument("--plot", metavar="FILE.png", help="the parameters run by run (default: FIRST-repeatability.png; with --report, only the report's)")
    p.add_argument("--report", metavar="DIR", help="also write repeatability.html and its plots in DIR")
    p.set_defaults(func=cmd_repeatability)


def expand(paths: list[str]) -> list[str]:
    """Recordings as given; a folder stands for its *.h5 files (`rig.fleet.many.recordings_in`)."""
    from ..fleet.many import recordings_in

    out: list[str] = []
    for p in paths:
        if Path(p).is_dir():
            found = recordings_in(Path(p))
            if not found:
                raise UsageError(f"{p} holds no recordings (*.h5); record some with rig run, or give the files")
            out += [str(f) for f in found]
        elif not Path(p).exists():  # before any fit: a row of the table, and a plot, were made without it
            raise UsageError(f"{p} does not exist; check the path (rig demo writes to rig-output/)")
        else:
            out.append(p)
    seen: dict[str, str] = {}
    for p in out:  # one file given twice compares it with itself: "alike", or errors judged on copies
        key = str(Path(p).resolve())
        if key in seen:
            raise UsageError(f"{p} is given twice (as {seen[key]} too); give each recording once")
        seen[key] = p
    return out


def fit_each(args: argparse.Namespace, paths: list[str], what: str):
    """Every recording fitted with --model (rig.recordings.recording_fits), in input order, with progress on stderr."""
    from ..fleet.many import fit_all_for_comparison
    from ..models.fitting.progress import ProgressCounter
    from ..recordings.recording_fits import FitJob
    from .shared import catalogue_of, parse_model_option, progress_line

    if args.model:
        parse_model_option(args.model, catalogue_of(args))  # a model that does not parse is refused before any work
    timeout_s = cluster_timeout(args)
    effects = tuple(str(Path(f).resolve()) for f in args.effects)
    window = (getattr(args, "z_min", None), getattr(args, "z_max", None))
    jobs = [FitJob(p, args.model, effects, *window) for p in paths]
    done: dict[str, object] = {}
    with progress_line(args, what) as progress:
        counter = ProgressCounter(progress, len(jobs))
        try:
            for r in fit_all_for_comparison(jobs, max(1, args.jobs), args.scheduler, timeout_s):
                done[r.path] = r
                counter.step(f"fitted {len(done)} of {len(jobs)} recordings")
        except ValueError as e:
            raise UsageError(str(e)) from None
        counter.finish()
    return [done[p] for p in paths]


def _outputs(args: argparse.Namespace, first: str, suffix: str) -> Path | None:
    """The plot's path: --plot, else beside the first recording; None with --report and no --plot (the plot is the
    report's own, and nothing is written beside the inputs)."""
    if args.report:
        refuse_unwritable(Path(args.report), "--report", folder=True)
        if not args.plot:
            return None
    plot = Path(args.plot) if args.plot else Path(first).with_name(f"{Path(first).stem}-{suffix}.png")
    refuse_unwritable(plot, "--plot")
    return plot


def _runs(paths: list[str]):
    from protocols.recording import utc_now

    from .. import package_version
    from ..reports.run_info import run_info

    out = []
    for p in paths:
        try:
            out.append(run_info(p, utc_now(), package_version()))
        except (OSError, ValueError):
            pass
    return out


def cmd_compare_recordings(args: argparse.Namespace) -> int:
    """`rig compare a.h5 b.h5 [...]`: the same model fitted to each, and every pair's differences judged."""
    from ..recordings.comparison import differences
    from ..reports.comparison_json import compare_document
    from ..reports.comparison_plots import plot_overlay
    from ..reports.comparison_text import render_compare
    from ..reports.report_pages import write_compare_page
    from ..reports.result_json import dumps

    if args.models:
        raise UsageError("--models compares models on one recording; with several recordings give one --model, fitted "
                         "to each (or compare the models recording by recording)")
    paths = expand(args.recording)
    if len(paths) < 2:
        raise UsageError(f"rig compare of recordings needs two or more, and got {len(paths)}; give more recordings, or "
                         "--models to compare models on one")
    plot = _outputs(args, paths[0], "compare")
    results = fit_each(args, paths, "rig compare")
    if all(r.error for r in results):
        raise UsageError("; ".join(f"{r.name}: {r.error}" for r in results))
    pairs = differences(results)
    text = render_compare(results, pairs)
    plots = [plot_overlay(results, plot)] if plot else []
    page = None
    if args.report:
        extra = [plot_overlay(results, Path(args.report) / "compare-overlay.png")]
        page = write_compare_page(results, pairs, extra, args.report, text, _runs(paths))
        plots = plots or extra
    if args.json:
        print(dumps(compare_document(results, pairs, plots, page)))
    else:
        for r in results:
            for note in r.notes:
                print(f"note: {r.name}: {note}")
        print(text)
        print(f"\nplot: {plots[0]}" + (f"\nreport: {page}" if page else ""))
    return 2 if any(r.error for r in results) else 0


def cmd_repeatability(args: argparse.Namespace) -> int:
    """`rig repeatability run1.h5 run2.h5 ...`: the run-to-run scatter of each parameter against its errors."""
    from ..recordings.comparison import scatter
    from ..reports.comparison_json import repeatability_document
    from ..reports.comparison_plots import plot_runs
    from ..reports.comparison_text import render_repeatability
    from ..reports.report_pages import write_repeatability_page
    from ..reports.result_json import dumps

    paths = expand(args.recording)
    if len(paths) < 2:
        raise UsageError(f"repeatability needs two or more runs of one camera and setting, and got {len(paths)}; "
                         "record the run again (rig run ... -o run2.h5) and give every run")
    plot = _outputs(args, paths[0], "repeatability")
    results = fit_each(args, paths, "rig repeatability")
    try:
        scatters = scatter(results)
    except ValueError as e:
        raise UsageError(f"{e} ({'; '.join(f'{r.name}: {r.error}' for r in results if r.error)})") from None
    text = render_repeatability(results, scatters)
    plots = [plot_runs(results, scatters, plot)] if plot else []
    page = None
    if args.report:
        extra = [plot_runs(results, scatters, Path(args.report) / "repeatability-runs.png")]
        page = write_repeatability_page(results, scatters, extra, args.report, text, _runs(paths))
        plots = plots or extra
    if args.json:
        print(dumps(repeatability_document(results, scatters, plots, page)))
    else:
        print(text)
        print(f"\nplot: {plots[0]}" + (f"\nreport: {page}" if page else ""))
    return 2 if any(r.error for r in results) else 0


def fit_many_command(args: argparse.Namespace) -> int:
    """rig fit --many DIR: the paper's fit of every recording in a folder, in a pool of processes."""
    from ..fleet.many import fit_many, recordings_in
    from ..reports.result_json import dumps

    folder = Path(args.recording)
    if not folder.is_dir():
        raise UsageError(f"--many takes a folder of recordings, and {folder} is not one; give the folder, or drop --many")
    if args.model or args.plot or args.table or args.report or args.z_min is not None or args.z_max is not None:
        raise UsageError("--many fits the paper's model of each whole recording; drop --model, --plot, --table, --report "
                         "and the --z-min/--z-max window, or fit the recordings one by one")
    paths = recordings_in(folder)
    if not paths:
        raise UsageError(f"{folder} holds no recordings (*.h5); record some with rig run, or give another folder")
    timeout_s = cluster_timeout(args)
    failed = 0
    if not args.json:
        print(f"{'recording':<32} {'k':>12} {'+/-':>9} {'lambda':>9} {'+/-':>9} {'headline':>9}  verdict")
    rows = fit_many(paths, args.jobs, scheduler=args.scheduler, timeout_s=timeout_s)
    for row in _usage_errors(rows):
        failed += bool(row.error)
        if args.json:
            print(dumps(row.document, line=True) if row.document else dumps({"file": str(row.path), "error": row.error}, line=True))
        elif row.error:
            print(f"{row.path.name:<32} error: {row.error}")
        else:
            print(f"{row.path.name:<32} {row.k:>12.6g} {row.se_k:>9.2g} {row.lam:>9.5f} {row.se_lam:>9.2g} "
                  f"{row.headline_pct:>8.2f}%  {row.verdict}")
        sys.stdout.flush()
    return 2 if failed == len(paths) else 0


def _usage_errors(rows):
    """The rows, with a ValueError of the engine (a --scheduler that does not answer) as the one-line usage error."""
    try:
        yield from rows
    except ValueError as e:
        raise UsageError(str(e)) from None
