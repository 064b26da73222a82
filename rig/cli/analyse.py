"""Commands that analyse a recording: `rig fit`, `rig compare`, `rig diagnose`."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from .memory import return_large_blocks_at_once
from .options import EXIT_UNDETERMINED, refuse_unwritable, verbosity
from .usage import UsageError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the analysis commands to the `rig` parser; what they share comes from the parents below."""
    shared, window, held_out = _shared_options(), _window_options(), _held_out_options()

    p = sub.add_parser("fit", parents=[shared, window, held_out], help="fit sigma_Z = k Z^lambda to a recording")
    p.add_argument("--model", help="fit a composed model instead, e.g. active+slant_range+noise_floor")
    p.add_argument("--plot", metavar="FILE.png", help="write a sigma-vs-range plot here (any format matplotlib writes: "
                                                      ".png, .pdf, .svg, ...)")
    p.add_argument("--table", metavar="STOPS.csv", help="write the per-stop table here (range, pixels, samples, "
                                                       "measured and model sigma, fill rate; CSV)")
    p.add_argument("--many", action="store_true", help="RECORDING is a folder: fit every *.h5 in it, one process per "
                                                       "core (--jobs), a line each (with --json: one document a line)")
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("compare", parents=[shared, window, held_out],
                       help="fit several models and show their errors side by side")
    p.add_argument("--models", required=True, help="comma-separated, e.g. active,active+slant_range")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("diagnose", parents=[shared], help="where the model fails and which physical effect is most likely missing")
    p.add_argument("--model", help="model to start from (default: active with the projector on, passive without)")
    p.add_argument("--out", help="folder for the plots and the HTML report (default: RECORDING-diagnosis/)")
    p.set_defaults(func=cmd_diagnose)


def _shared_options() -> argparse.ArgumentParser:
    """What fit, compare and diagnose all take: the recording, --json, --effects and --jobs."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("recording")
    p.add_argument("--json", action="store_true", help="print the result as JSON (docs/json.md)")
    p.add_argument("--effects", action="append", default=[], metavar="FILE.py",
                   help="load effects you wrote (a Python file using @effect; docs/effects.md); may be repeated")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                   help="processes for the work that runs in parallel: the held-out score's refits, --many, the "
                        "diagnosis's candidate effects (default: one per core)")
    return p


def _window_options() -> argparse.ArgumentParser:
    """The window of ranges to fit (fit, compare): --z-min, --z-max, in metres."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--z-min", type=float, metavar="M", help="use only pixels with mean range >= this (m)")
    p.add_argument("--z-max", type=float, metavar="M", help="use only pixels with mean range <= this (m)")
    return p


def _held_out_options() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--no-held-out", action="store_true", help="skip the leave-one-stop-out score (faster)")
    return p


def catalogue_of(args: argparse.Namespace):
    """The built-in effects, installed plugins' and those of every --effects file."""
    from ..models import Catalogue

    cat = Catalogue.default()
    for path in getattr(args, "effects", []) or []:
        cat = cat.with_file(path)
    return cat


def _model_data(path: str, z_min: float | None = None, z_max: float | None = None):
    """(ModelData of the recording in the --z-min/--z-max window, its notes), from one opening of the file."""
    from protocols.recording import Recording

    from ..analysis import in_window, recording_notes
    from ..models import load_samples

    try:
        with Recording(path) as rec:
            d = load_samples(rec).positive_variance()
            notes = recording_notes(rec)
        return in_window(d, z_min, z_max), notes
    except ValueError as e:
        raise UsageError(str(e)) from None


def _check_window(args: argparse.Namespace) -> None:
    """Refuse a --z-min/--z-max window that can hold no pixel, before the recording is read."""
    from ..analysis import check_window

    try:
        check_window(getattr(args, "z_min", None), getattr(args, "z_max", None))
    except ValueError as e:
        raise UsageError(str(e)) from None


def _refuse_plot_format(path: str | None) -> None:
    """Refuse a --plot file matplotlib cannot write, before the work (one line, naming the suffixes it can)."""
    if path is None:
        return
    from ..reports.sigma_plot import plot_format_problem

    problem = plot_format_problem(path)
    if problem:
        raise UsageError(f"cannot write --plot {path}: {problem}")


def _model_notes(model, d) -> list[str]:
    """Notes about fitting `model` to `d` (rig.diagnosis.base_mismatch: a base that does not fit the recording)."""
    from ..diagnosis import base_mismatch

    note = base_mismatch(model, d)
    return [note] if note else []


def _parse_model(text: str, catalogue=None):
    from ..models import parse_model

    try:
        return parse_model(text, catalogue)
    except ValueError as e:
        raise UsageError(str(e)) from None


def progress_line(args: argparse.Namespace, title: str):
    """The terminal's progress line for this command (silent when stderr is not a terminal, or with -q)."""
    from ..reports.work_progress import WorkProgressLine

    return WorkProgressLine(title, verbosity(args))


def cmd_fit(args: argparse.Namespace) -> int:
    from ..analysis import fit_recording
    from ..diagnosis import headline
    from ..models.progress import ProgressCounter

    _check_window(args)
    _refuse_plot_format(args.plot)
    refuse_unwritable(args.plot, "--plot")
    refuse_unwritable(args.table, "--table")
    if not args.model and not args.many:
        return_large_blocks_at_once()
    if args.many:
        return _fit_many(args)
    if args.model:
        return _fit_model(args)
    if args.effects:
        catalogue_of(args)  # a broken effects file is an error even when no model uses it yet
    with progress_line(args, "rig fit") as progress:
        counter = ProgressCounter(progress, 3)
        try:
            r = fit_recording(args.recording, z_min_m=args.z_min, z_max_m=args.z_max, counter=counter)
        except ValueError as e:
            raise UsageError(str(e)) from None
        counter.step("headline error: every statistic the paper's fit predicts")
        h = headline(r.fit, r.samples.positive_variance())
        counter.finish()
    if args.json:
        from ..reports.result_json import document, dumps, fit_json

        print(dumps(document("fit", args.recording, r.notes, [fit_json(r.fit, h)], best=r.fit.model.name,
                             window_m=(args.z_min, args.z_max))))
    else:
        for note in r.notes:
            print(f"note: {note}")
        mode = "projector on" if r.projector_on else "projector off"
        print(f"{r.path}: {r.protocol}, {mode}")
        print(r.fit.report())
        print(f"    headline error: {h}")
        print(_fix_line(h) or f"    (what is missing? rig diagnose {args.recording})")
    if args.plot:
        from ..reports.sigma_plot import SigmaSeries, plot_sigma_vs_range

        out = plot_sigma_vs_range([SigmaSeries(r.path.stem, r.measured, r.fit, "tab:red")], args.plot)
        print(f"plot: {out}", file=sys.stderr if args.json else sys.stdout)  # stdout holds the JSON alone
    _write_table(args, r.fit, r.samples)
    return exit_status([h])


def _fit_many(args: argparse.Namespace) -> int:
    """rig fit --many DIR: the paper's fit of every recording in a folder, in a pool of processes."""
    from ..many import fit_many, recordings_in
    from ..reports.result_json import dumps

    folder = Path(args.recording)
    if not folder.is_dir():
        raise UsageError(f"--many takes a folder of recordings, and {folder} is not one; give the folder, or drop --many")
    if args.model or args.plot or args.table or args.z_min is not None or args.z_max is not None:
        raise UsageError("--many fits the paper's model of each whole recording; drop --model, --plot, --table and the "
                         "--z-min/--z-max window, or fit the recordings one by one")
    paths = recordings_in(folder)
    if not paths:
        raise UsageError(f"{folder} holds no recordings (*.h5); record some with rig run, or give another folder")
    failed = 0
    if not args.json:
        print(f"{'recording':<32} {'k':>12} {'+/-':>9} {'lambda':>9} {'+/-':>9} {'headline':>9}  verdict")
    for row in fit_many(paths, args.jobs):
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


def _fit_model(args: argparse.Namespace) -> int:
    from ..diagnosis import headline, held_out_nll
    from ..diagnosis.scores import held_out_folds
    from ..models.progress import ProgressCounter

    model = _parse_model(args.model, catalogue_of(args))
    with progress_line(args, "rig fit") as progress:
        counter = ProgressCounter(progress, 3)
        counter.step("reading the recording")
        d, notes = _model_data(args.recording, args.z_min, args.z_max)
        notes = notes + _model_notes(model, d)
        if not args.no_held_out:
            counter.expect(2 + len(np.unique(held_out_folds(d))))
        counter.step(f"fitting {model.name}")
        try:
            f = model.fit(d)
        except ValueError as e:
            raise UsageError(str(e)) from None
        counter.step("headline error: every statistic the model predicts")
        h = headline(f, d)
        nll = None if args.no_held_out else held_out_nll(model, d, f, counter=counter, jobs=max(1, args.jobs))
        counter.finish()
    if args.json:
        from ..reports.result_json import document, dumps, fit_json

        print(dumps(document("fit", args.recording, notes, [fit_json(f, h, held_out_nll=nll)], best=model.name,
                             window_m=(args.z_min, args.z_max))))
        _write_table(args, f, d)
        return exit_status([h])
    for note in notes:
        print(f"note: {note}")
    print(f.report())
    print(f"    headline error: {h}")
    if not h.determined:
        print(_fix_line(h))
    if nll is not None:
        print(f"    held-out negative log-likelihood per degree of freedom: {nll:.6f}")
    _write_table(args, f, d)
    return exit_status([h])


def cmd_compare(args: argparse.Namespace) -> int:
    from ..diagnosis import headline, held_out_nll
    from ..diagnosis.scores import held_out_folds
    from ..models.progress import ProgressCounter

    _check_window(args)
    cat = catalogue_of(args)
    models = [_parse_model(m, cat) for m in args.models.split(",")]
    rows = []
    with progress_line(args, "rig compare") as progress:
        counter = ProgressCounter(progress, 1 + 2 * len(models))
        counter.step("reading the recording")
        d, notes = _model_data(args.recording, args.z_min, args.z_max)
        firsts = {m.base.name: m for m in reversed(models)}  # one note a base, naming its first model
        notes = notes + [n for m in models if firsts[m.base.name] is m for n in _model_notes(m, d)]
        if not args.no_held_out:
            counter.expect(len(models) * (2 + len(np.unique(held_out_folds(d)))))
        for m in models:
            counter.step(f"fitting {m.name}")
            try:
                f = m.fit(d)
            except ValueError as e:
                raise UsageError(str(e)) from None
            counter.step(f"headline error of {m.name}")
            rows.append((m, f, headline(f, d), None if args.no_held_out else held_out_nll(m, d, f, counter=counter, jobs=max(1, args.jobs))))
        counter.finish()
    best = min(rows, key=lambda r: r[1].bic)
    if args.json:
        from ..reports.result_json import document, dumps, fit_json

        print(dumps(document("compare", args.recording, notes, [fit_json(f, h, held_out_nll=nll) for _, f, h, nll in rows],
                             best=best[0].name, window_m=(args.z_min, args.z_max))))
        return exit_status([h for _, _, h, _ in rows])
    for note in notes:
        print(f"note: {note}")
    base_bic = rows[0][1].bic
    w = max(len(m.name) for m, *_ in rows) + 2
    print(f"{'model':<{w}} {'free':>4} {'headline error':>15} {'noise alone':>12} {'within noise':>14} {'dBIC':>12} {'held-out NLL/dof':>17}")
    for m, f, h, nll in rows:
        within = {"within noise": "yes", "beyond noise": "no"}.get(h.state, h.state)
        print(f"{m.name:<{w}} {f.n_free:>4} {h.error_pct:>13.2f} % {h.noise_pct:>10.2f} % {within:>14} "
              f"{f.bic - base_bic:>12.1f} {'' if nll is None else f'{nll:.6f}':>17}")
    print(f"\nLowest BIC: {best[0].name}; its headline error is {best[2]}.")
    undetermined = [h for _, _, h, _ in rows if not h.determined]
    if undetermined:
        print(f"{', '.join(m.name for m, _, h, _ in rows if not h.determined)}: {undetermined[0].lambda_status.reason}.")
        print(_fix_line(undetermined[0]).strip())
    return exit_status([h for _, _, h, _ in rows])


def cmd_diagnose(args: argparse.Namespace) -> int:
    from ..diagnosis import diagnose, render_text
    from ..models.progress import WorkProgress

    cat = catalogue_of(args)
    out = Path(args.out) if args.out else Path(args.recording).with_suffix("").with_name(Path(args.recording).stem + "-diagnosis")
    _check_writable(out)
    model = _parse_model(args.model, cat) if args.model else None
    with progress_line(args, "rig diagnose") as progress:
        progress(WorkProgress("reading the recording", 0, 1))
        d, notes = _model_data(args.recording)
        if model is not None:
            notes = notes + _model_notes(model, d)
        steps = [0]

        def fits(p: WorkProgress) -> None:  # the diagnosis's own steps; the report is one more
            steps[0] = p.total
            if not p.finished:
                progress(p)

        try:
            diag = diagnose(d, model, source=args.recording, catalogue=cat, progress=fits, jobs=max(1, args.jobs))
        except ValueError as e:
            raise UsageError(str(e)) from None
        progress(WorkProgress("writing the plots and the report", steps[0], steps[0] + 1))
        plots, page = _write_report(diag, out, args.recording)
        progress(WorkProgress("done", steps[0] + 1, steps[0] + 1, finished=True))
    status = exit_status([st.headline for st in diag.steps])
    if args.json:
        from ..reports.result_json import diagnosis_json, document, dumps

        fits, part = diagnosis_json(diag, plots, page)
        print(dumps(document("diagnose", args.recording, notes, fits, best=diag.final_fit.model.name, diagnosis=part)))
        return status
    for note in notes:
        print(f"note: {note}")
    print(render_text(diag))
    print(f"\nPlots: {', '.join(str(p) for p in plots)}\nReport: {page}")
    return status


def _write_table(args: argparse.Namespace, fit, d) -> None:
    """`--table FILE`: the per-stop table of `fit` on its pixels `d` (rig.reports.stop_table)."""
    if not args.table:
        return
    from ..reports.stop_table import stop_rows, write_stop_table

    out = write_stop_table(stop_rows(fit, d), args.table)
    print(f"table: {out}", file=sys.stderr if args.json else sys.stdout)


def exit_status(headlines) -> int:
    """0, or EXIT_UNDETERMINED when a model the command fitted has a lambda the data do not determine."""
    return EXIT_UNDETERMINED if any(not h.determined for h in headlines) else 0


def _fix_line(h) -> str | None:
    """The way to a determined lambda, as a line of the text report; None when it is determined."""
    return None if h.determined else f"    to determine lambda: {h.lambda_status.fix}"


def _write_report(diag, out: Path, recording: str) -> tuple[list[Path], Path]:
    """Plots and page are made in a folder beside `out`, then moved in file by file (each move atomic), and
    the previous run's diagnosis files that this one did not make are removed: a diagnosis killed while it
    works leaves the previous report whole, never a mix of old and new plots."""
    import os
    import shutil

    from protocols.recording import utc_now

    from .. import package_version
    from ..reports.diagnosis_html import write_html
    from ..reports.diagnosis_plots import write_plots
    from ..reports.run_info import run_info

    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    work = out.parent / f".{out.name}.{os.getpid()}.writing"
    try:
        plots = write_plots(diag, work)
        page = write_html(diag, plots, work, run_info(recording, utc_now(), package_version()))
        made = [*plots, page]
        for old in out.glob("diagnosis*"):
            if old.is_file() and old.name not in {p.name for p in made}:
                old.unlink()
        for p in made:
            os.replace(p, out / p.name)
    except BaseException:
        if created and not any(out.iterdir()):  # a folder this command made and never filled (a full disk)
            out.rmdir()
        raise
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return [out / p.name for p in plots], out / page.name


def _check_writable(folder: Path) -> None:
    """Refuse before the work, not after it, when the report cannot be written (into `folder`, through a
    working folder beside it)."""
    from ..reports.writable import output_problem

    problem = output_problem(folder, folder=True) or output_problem(folder.parent, folder=True)
    if problem:
        raise UsageError(f"cannot write the report to {folder}: {problem}; pass --out a folder you can write to")
