"""Commands that analyse a recording: `rig fit`, `rig compare`, `rig diagnose`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .options import EXIT_UNDETERMINED, refuse_unwritable
from .shared import (catalogue_of, check_window, fit_or_refuse, model_data, parse_model_option, progress_line,
                     shared_options, window_options)
from .usage import UsageError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the analysis commands to the `rig` parser; what they share comes from the parents below."""
    shared, window, held_out = shared_options(), window_options(), _held_out_options()

    from .recordings import cluster_options

    p = sub.add_parser("fit", parents=[shared, window, held_out, cluster_options()],
                       help="fit sigma_Z = k Z^lambda to a recording")
    p.add_argument("--model", help="fit a composed model instead, e.g. active+slant_range+noise_floor")
    p.add_argument("--plot", metavar="FILE.png", help="write a sigma-vs-range plot here (any format matplotlib writes: "
                                                      ".png, .pdf, .svg, ...)")
    p.add_argument("--table", metavar="STOPS.csv", help="write the per-stop table here (range, pixels, samples, "
                                                       "measured and model sigma, fill rate, accuracy against the "
                                                       "stage; CSV)")
    p.add_argument("--many", action="store_true", help="RECORDING is a folder: fit every *.h5 in it, one process per "
                                                       "core (--jobs) or on a Dask cluster (--scheduler), a line each "
                                                       "(with --json: one document a line)")
    p.add_argument("--report", metavar="DIR", help="also write fit.html (run, fit, plot) in DIR")
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("compare", parents=[shared_options(several=True), window, held_out, cluster_options()],
                       help="fit several models to one recording, or one model to several recordings, and compare")
    p.add_argument("--models", help="one recording: the models to compare, comma-separated, e.g. active,active+slant_range")
    p.add_argument("--model", help="several recordings: the model fitted to each (default: the paper's power law)")
    p.add_argument("--plot", metavar="FILE.png", help="several recordings: the overlay of sigma against range "
                                                      "(default: FIRST-compare.png beside the first recording; with --report, only the report's)")
    p.add_argument("--report", metavar="DIR", help="several recordings: also write compare.html and its plot in DIR")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("accuracy", parents=[shared_options()],
                       help="the depth against the stage's truth: each stop's figures and the bias loop")
    p.set_defaults(func=cmd_accuracy)

    p = sub.add_parser("diagnose", parents=[shared], help="where the model fails and which physical effect is most likely missing")
    p.add_argument("--model", help="model to start from (default: active with the projector on, passive without)")
    p.add_argument("--out", help="folder for the plots and the HTML report (default: RECORDING-diagnosis/)")
    p.set_defaults(func=cmd_diagnose)


def _held_out_options() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--no-held-out", action="store_true", help="skip the leave-one-stop-out score (faster)")
    return p


def _refuse_plot_format(path: str | None) -> None:
    """Refuse a --plot file matplotlib cannot write, before the work (one line, naming the suffixes it can)."""
    if path is None:
        return
    from ..reports.sigma_plot import plot_format_problem

    problem = plot_format_problem(path)
    if problem:
        raise UsageError(f"cannot write --plot {path}: {problem}")


def _model_notes(model, d) -> list[str]:
    """Notes about fitting `model` to `d` (rig.diagnosis.base_mismatch: a base that does not fit the recording; the
    measured light's clipped IR)."""
    from ..diagnosis import base_mismatch

    from ..models.data.pattern_light import light_note

    notes = [base_mismatch(model, d)]
    if any(e.name == "measured_light" for e in model.effects):
        notes.append(light_note(d))
    return [n for n in notes if n]


def cmd_fit(args: argparse.Namespace) -> int:
    from ..analysis import fit_recording
    from ..diagnosis import headline
    from ..models.fitting.progress import ProgressCounter

    check_window(args)
    _refuse_plot_format(args.plot)
    refuse_unwritable(args.plot, "--plot")
    refuse_unwritable(args.table, "--table")
    if args.scheduler and not args.many:
        raise UsageError("--scheduler runs the fits of many recordings on a cluster; add --many (and give a folder), or drop it")
    if args.report:
        refuse_unwritable(args.report, "--report", folder=True)
    if args.many:
        from .recordings import fit_many_command

        return fit_many_command(args)
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
        acc = _accuracy(args.recording, r.fit, r.samples)
        counter.finish()
    if args.json:
        from ..accuracy import accuracy_json
        from ..reports.result_json import document, dumps, fit_json

        print(dumps(document("fit", args.recording, r.notes, [fit_json(r.fit, h)], best=r.fit.model.name,
                             window_m=(args.z_min, args.z_max), accuracy=accuracy_json(acc))))
    else:
        from ..accuracy import accuracy_lines

        for note in r.notes:
            print(f"note: {note}")
        mode = "projector on" if r.projector_on else "projector off"
        print(f"{r.path}: {r.protocol}, {mode}" + (f"; the region {r.region}" if r.region else ""))
        print(r.fit.report())
        print(f"    headline error: {h}")
        print(_fix_line(h) or f"    (what is missing? rig diagnose {args.recording})")
        for line in accuracy_lines(acc):
            print(line)
    _fit_report(args, r.fit, r.samples.positive_variance(), h, r.notes, acc)
    if args.plot:
        from ..reports.sigma_plot import SigmaSeries, plot_sigma_vs_range

        out = plot_sigma_vs_range([SigmaSeries(r.path.stem, r.measured, r.fit, "tab:red")], args.plot)
        print(f"plot: {out}", file=sys.stderr if args.json else sys.stdout)  # stdout holds the JSON alone
    _write_table(args, r.fit, r.samples, acc)
    return exit_status([h])


def _fit_model(args: argparse.Namespace) -> int:
    from ..diagnosis import headline, held_out_nll
    from ..diagnosis.scores import held_out_folds
    from ..models.fitting.progress import ProgressCounter

    model = parse_model_option(args.model, catalogue_of(args))
    with progress_line(args, "rig fit") as progress:
        counter = ProgressCounter(progress, 3)
        counter.step("reading the recording")
        d, notes = model_data(args.recording, args.z_min, args.z_max)
        notes = notes + _model_notes(model, d)
        if not args.no_held_out:
            counter.expect(2 + len(np.unique(held_out_folds(d))))
        counter.step(f"fitting {model.name}")
        f = fit_or_refuse(model, d)
        counter.step("headline error: every statistic the model predicts")
        h = headline(f, d)
        nll = None if args.no_held_out else held_out_nll(model, d, f, counter=counter, jobs=max(1, args.jobs))
        acc = _accuracy(args.recording, f, d)
        counter.finish()
    if args.json:
        from ..accuracy import accuracy_json
        from ..reports.result_json import document, dumps, fit_json

        print(dumps(document("fit", args.recording, notes, [fit_json(f, h, held_out_nll=nll)], best=model.name,
                             window_m=(args.z_min, args.z_max), accuracy=accuracy_json(acc))))
        _write_table(args, f, d, acc)
        _fit_report(args, f, d, h, notes, acc)
        return exit_status([h])
    from ..accuracy import accuracy_lines

    for note in notes:
        print(f"note: {note}")
    print(f.report())
    print(f"    headline error: {h}")
    if not h.determined:
        print(_fix_line(h))
    if nll is not None:
        print(f"    held-out negative log-likelihood per degree of freedom: {nll:.6f}")
    for line in accuracy_lines(acc):
        print(line)
    _write_table(args, f, d, acc)
    _fit_report(args, f, d, h, notes, acc)
    return exit_status([h])


def cmd_compare(args: argparse.Namespace) -> int:
    from ..diagnosis import headline, held_out_nll
    from ..diagnosis.scores import held_out_folds
    from ..models.fitting.progress import ProgressCounter

    check_window(args)
    if len(args.recording) > 1 or Path(args.recording[0]).is_dir():
        from .recordings import cmd_compare_recordings

        return cmd_compare_recordings(args)
    args.recording = args.recording[0]
    if args.models is not None and not [m for m in args.models.split(",") if m.strip()]:
        raise UsageError(f"--models {args.models!r} names no model; give them comma-separated, e.g. --models "
                         "active,active+slant_range")
    if not args.models:
        raise UsageError("rig compare of one recording needs --models (e.g. --models active,active+slant_range); to "
                         "compare recordings, give two or more")
    if args.model or args.plot or args.report:
        raise UsageError("--model, --plot and --report are for comparing several recordings; with one, give --models")
    cat = catalogue_of(args)
    models = [parse_model_option(m.strip(), cat) for m in args.models.split(",") if m.strip()]
    rows = []
    with progress_line(args, "rig compare") as progress:
        counter = ProgressCounter(progress, 1 + 2 * len(models))
        counter.step("reading the recording")
        d, notes = model_data(args.recording, args.z_min, args.z_max)
        firsts = {m.base.name: m for m in reversed(models)}  # one note a base, naming its first model
        notes = notes + [n for m in models if firsts[m.base.name] is m for n in _model_notes(m, d)]
        if not args.no_held_out:
            counter.expect(len(models) * (2 + len(np.unique(held_out_folds(d)))))
        for m in models:
            counter.step(f"fitting {m.name}")
            f = fit_or_refuse(m, d)
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
    from ..models.fitting.progress import WorkProgress

    cat = catalogue_of(args)
    out = Path(args.out) if args.out else Path(args.recording).with_suffix("").with_name(Path(args.recording).stem + "-diagnosis")
    _check_writable(out)
    model = parse_model_option(args.model, cat) if args.model else None
    with progress_line(args, "rig diagnose") as progress:
        progress(WorkProgress("reading the recording", 0, 1))
        d, notes = model_data(args.recording)
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


def cmd_accuracy(args: argparse.Namespace) -> int:
    """`rig accuracy REC`: each stop's accuracy against the stage (rig.accuracy) and the bias loop: which calibration
    effect is missing, added one at a time while the evidence is very strong."""
    from protocols.recording import Recording

    from ..accuracy import accuracy_json, accuracy_lines, accuracy_of
    from ..accuracy.bias_loop import bias_groups, diagnose_bias, stage_tolerance
    from ..accuracy.path_text import bias_path_json, bias_path_lines
    from ..accuracy.bias_effects import BIAS_EFFECTS, BiasEffectFileError, load_bias_effects

    users: dict = {}
    try:
        for f in args.effects:  # the user's bias effects join the loop's catalogue
            users.update(load_bias_effects(f))
    except BiasEffectFileError as e:
        raise UsageError(str(e)) from None
    with progress_line(args, "rig accuracy"):
        d, notes = model_data(args.recording)
        with Recording(args.recording) as rec:
            protocol, params, tolerance = rec.protocol, rec.protocol_params, stage_tolerance(rec)
        acc = accuracy_of(d, None, protocol, params)
        groups = bias_groups(d, tolerance) if not (acc.why_not or acc.walls) else None
        dg = diagnose_bias(groups, {**BIAS_EFFECTS, **users}) if groups is not None else None
    if args.json:
        import json

        doc = {"schema": "rig.accuracy/1", "file": str(args.recording), "notes": notes, "accuracy": accuracy_json(acc),
               "bias_path": bias_path_json(dg) if dg is not None else None}
        print(json.dumps(doc, indent=1))
        return 0
    for note in notes:
        print(f"note: {note}")
    print(f"Accuracy of {args.recording} against the stage's truth")
    for s in acc.stops:
        print(f"  {s.stop}: truth {s.truth_m:.4f} m ({s.truth_source}), depth accuracy {s.depth_accuracy_pct:+.3f} % "
              f"(+/- {s.depth_accuracy_se_pct:.3f}), spatial RMS {1e3 * s.spatial_rms_m:.3g} mm (noise alone "
              f"{1e3 * s.spatial_rms_noise_m:.3g} mm), fill {100 * s.fill_rate:.1f} %")
    for line in accuracy_lines(acc):
        print(line.strip())
    if dg is None:
        print("The bias loop needs three stops or more whose distance is known, on a wall facing the camera.")
        return 0
    print("\n".join(bias_path_lines(dg)))
    return 0


def _fit_report(args: argparse.Namespace, fit, d, h, notes: list[str], acc=None) -> None:
    """`--report DIR`: fit.html and its plot (rig.reports.report_pages), with the accuracy against the stage."""
    if not args.report:
        return
    from ..reports.report_pages import fit_report, fit_report_text

    page = fit_report(args.recording, fit, d, h, fit_report_text(fit, h, notes, acc), args.report, notes)
    print(f"report: {page}", file=sys.stderr if args.json else sys.stdout)


def _accuracy(path, fit, d):
    """The recording's accuracy against the stage's truth (rig.accuracy). The spatial RMS's noise is from each pixel's
    own variance: the fit's prediction for every pixel was 0.9 s of a full sweep's 3 s `rig fit`."""
    from protocols.recording import Recording

    from ..accuracy import accuracy_of

    with Recording(path) as rec:
        protocol, params = rec.protocol, rec.protocol_params
    return accuracy_of(d, None, protocol, params)


def _write_table(args: argparse.Namespace, fit, d, acc=None) -> None:
    """`--table FILE`: the per-stop table of `fit` on its pixels `d` (rig.reports.stop_table), with the stops'
    accuracy `acc` where given."""
    if not args.table:
        return
    from ..reports.stop_table import stop_rows, write_stop_table

    out = write_stop_table(stop_rows(fit, d, acc), args.table)
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
