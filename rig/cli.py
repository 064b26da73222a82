"""The `rig` command line."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from drivers.errors import DeviceError

from .recording import RecordingError


class UsageError(ValueError):
    """Bad command-line input; the message says what to type instead."""


def _add_run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("experiment", nargs="?", help="experiment file (TOML); or give --protocol and options")
    p.add_argument("--protocol", choices=["perpendicular", "tilted"], help="protocol when no file is given")
    p.add_argument("--camera", help="camera device string (default fake:)")
    p.add_argument("--stage", help="stage device string (default fake: for perpendicular, none: for tilted)")
    p.add_argument("-o", "--output", help="recording to write (.h5)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted recording")
    p.add_argument("--frames", type=int, help="frames per stop")
    p.add_argument("--projector", choices=["on", "off"], help="IR projector")
    p.add_argument("--exposure-us", type=float)
    p.add_argument("--gain", type=float)
    p.add_argument("--stops", help="comma-separated distances in m (perpendicular)")
    p.add_argument("--tilt-deg", type=float, help="wall tilt (tilted)")


def cmd_run(args: argparse.Namespace) -> int:
    from protocols.experiment_file import Experiment, build_plan, load_experiment
    from protocols.runner import Runner

    from .devices import open_devices
    from .progress import TerminalProgress

    overrides: dict = {}
    if args.frames is not None:
        overrides["frames_per_stop" if (args.protocol or "perpendicular") == "perpendicular" else "frames"] = args.frames
    if args.projector:
        overrides["projector_on"] = args.projector == "on"
    if args.exposure_us is not None:
        overrides["exposure_us"] = args.exposure_us
    if args.gain is not None:
        overrides["gain"] = args.gain
    if args.stops:
        try:
            overrides["stops_m"] = [float(x) for x in args.stops.split(",")]
        except ValueError:
            raise UsageError(f"--stops {args.stops!r}: write distances in m separated by commas, e.g. 0.5,1.0,1.5") from None
    if args.tilt_deg is not None:
        overrides["tilt_deg"] = args.tilt_deg
    if args.experiment:
        exp = load_experiment(args.experiment)
        if overrides:
            params = {**exp.plan.params, **overrides}
            if exp.plan.name == "tilted" and "frames_per_stop" in params:
                params["frames"] = params.pop("frames_per_stop")
            exp.plan = build_plan(exp.plan.name, params)
    else:
        if not args.protocol:
            raise UsageError("give an experiment file (rig run FILE.toml) or --protocol perpendicular|tilted")
        exp = Experiment(build_plan(args.protocol, overrides), "fake:", "fake:" if args.protocol == "perpendicular" else "none:", None)
    camera = args.camera or exp.camera
    stage = args.stage or exp.stage
    output = Path(args.output) if args.output else exp.output
    if output is None:
        raise UsageError("no output file; pass -o FILE.h5 (or set output in the experiment file)")
    p = exp.plan.params
    devices = open_devices(camera, stage, tilt_deg=p.get("tilt_deg", 0.0), distance_m=p.get("distance_m", 1.0))
    print(f"rig: {exp.plan.name} experiment, camera {camera}, stage {stage} -> {output}", file=sys.stderr)
    result = Runner(devices.camera, devices.stage, progress=TerminalProgress(), sleep=devices.sleep).run(
        exp.plan, output, resume=args.resume)
    print(f"recorded {len(result.recorded)} stops ({len(result.skipped)} already there) in {result.path}")
    return 0


def _model_data(path: str):
    from .models import ModelData

    return ModelData.from_recording(path)


def _parse_model(text: str):
    from .models import parse_model

    try:
        return parse_model(text)
    except ValueError as e:
        raise UsageError(str(e)) from None


def cmd_fit(args: argparse.Namespace) -> int:
    from .analysis import fit_recording

    if args.model:
        return _fit_model(args)
    r = fit_recording(args.recording, z_min_m=args.z_min, z_max_m=args.z_max)
    if args.json:
        print(json.dumps(r.fit.to_dict(), indent=2))
    else:
        from .metrics import headline
        from .models import Model, ModelData, power_law

        mode = "projector on" if r.projector_on else "projector off"
        print(f"{r.path}: {r.protocol}, {mode}")
        print(r.fit.report())
        d = ModelData.from_recording(args.recording)
        if args.z_min is not None or args.z_max is not None:
            d = d.select((d.z_m >= (args.z_min or 0)) & (d.z_m <= (args.z_max or float("inf"))))
        print(f"    headline error: {headline(Model(power_law).fit(d), d)}")
        print(f"    (what is missing? rig diagnose {args.recording})")
    if args.plot:
        from .plots import SigmaSeries, plot_sigma_vs_range

        out = plot_sigma_vs_range([SigmaSeries(r.path.stem, r.measured, r.fit, "tab:red")], args.plot)
        print(f"plot: {out}")
    return 0


def _fit_model(args: argparse.Namespace) -> int:
    from .metrics import headline, held_out_nll

    model = _parse_model(args.model)
    d = _model_data(args.recording)
    if args.z_min is not None or args.z_max is not None:
        d = d.select((d.z_m >= (args.z_min or 0)) & (d.z_m <= (args.z_max or float("inf"))))
    try:
        f = model.fit(d)
    except ValueError as e:
        raise UsageError(str(e)) from None
    h = headline(f, d)
    if args.json:
        print(json.dumps({"model": model.name, "values": f.values, "errors": f.errors, "loglik": f.loglik,
                          "bic": f.bic, "headline_error_pct": h.error_pct, "noise_pct": h.noise_pct,
                          "within_noise": h.within_noise}, indent=2))
        return 0
    print(f.report())
    print(f"    headline error: {h}")
    if not args.no_held_out:
        print(f"    held-out negative log-likelihood per degree of freedom: {held_out_nll(model, d, f):.6f}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from .metrics import headline, held_out_nll

    d = _model_data(args.recording)
    models = [_parse_model(m) for m in args.models.split(",")]
    rows = []
    for m in models:
        try:
            f = m.fit(d)
        except ValueError as e:
            raise UsageError(str(e)) from None
        rows.append((m, f, headline(f, d), None if args.no_held_out else held_out_nll(m, d, f)))
    base_bic = rows[0][1].bic
    w = max(len(m.name) for m, *_ in rows) + 2
    print(f"{'model':<{w}} {'free':>4} {'headline error':>15} {'noise alone':>12} {'within noise':>13} {'dBIC':>12} {'held-out NLL/dof':>17}")
    for m, f, h, nll in rows:
        print(f"{m.name:<{w}} {f.n_free:>4} {h.error_pct:>13.2f} % {h.noise_pct:>10.2f} % {('yes' if h.within_noise else 'no'):>13} "
              f"{f.bic - base_bic:>12.1f} {'' if nll is None else f'{nll:.6f}':>17}")
    best = min(rows, key=lambda r: r[1].bic)
    print(f"\nLowest BIC: {best[0].name}; its headline error is {best[2]}.")
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    from .diagnose import diagnose, render_text
    from .diagnosis_report import write_html, write_plots

    d = _model_data(args.recording)
    model = _parse_model(args.model) if args.model else None
    try:
        diag = diagnose(d, model, source=args.recording)
    except ValueError as e:
        raise UsageError(str(e)) from None
    print(render_text(diag))
    out = Path(args.out) if args.out else Path(args.recording).with_suffix("").with_name(Path(args.recording).stem + "-diagnosis")
    plots = write_plots(diag, out)
    page = write_html(diag, plots, out)
    print(f"\nPlots: {', '.join(str(p) for p in plots)}\nReport: {page}")
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    from .scenarios import answer_path, hidden_scenario, record_scenario

    if args.scenario != "hidden":
        raise UsageError(f"unknown scenario {args.scenario!r}; the one scenario is 'hidden'")
    try:
        sc = hidden_scenario(args.seed, args.effect, width=args.width, frames=args.frames)
    except ValueError as e:
        raise UsageError(str(e)) from None
    out = record_scenario(sc, args.output)
    print(f"recorded {out} (seed {args.seed}); the hidden effect is written only to {answer_path(out)}")
    return 0


def cmd_paper_windows(args: argparse.Namespace) -> int:
    from .paper_windows import paper_windows_main

    return paper_windows_main(args.rest)


def cmd_import(args: argparse.Namespace) -> int:
    from .importer import import_main

    return import_main(args.rest)


def cmd_devices(args: argparse.Namespace) -> int:
    from .device_listing import devices_main

    return devices_main(args.rest)


def cmd_tui(args: argparse.Namespace) -> int:
    from .tui import tui_main

    return tui_main(args.rest)


def cmd_validate(args: argparse.Namespace) -> int:
    from .validation import main as validation_main

    return validation_main(args.rest)


def cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    return run_demo(out_dir=Path(args.out), frames=args.frames, width=848 if args.full_resolution else args.width,
                    seed=args.seed, depth_unit_mm=args.depth_unit_mm)


def cmd_stage_sim(args: argparse.Namespace) -> int:
    try:
        from fakes.stage_sim_cli import stage_sim_main
    except ModuleNotFoundError:
        raise UsageError("the stage simulators are not installed in this version") from None
    return stage_sim_main(args.rest)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rig", description="Depth-camera range-error rig: acquire, fit, diagnose.")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demo", help="simulated perpendicular experiments (projector on and off), fitted and plotted")
    p.add_argument("--out", default="rig-output", help="output folder (default rig-output/)")
    p.add_argument("--frames", type=int, default=300, help="frames per stop (default 300)")
    p.add_argument("--width", type=int, default=424, help="simulated image width in px (default 424, half of 848)")
    p.add_argument("--full-resolution", action="store_true", help="simulate the full 848x480 image (slower)")
    p.add_argument("--depth-unit-mm", type=float, default=0.1, help="depth unit of the simulated camera (default 0.1 mm)")
    p.add_argument("--seed", type=int, default=1)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("run", help="run an experiment (TOML file or options) and record it")
    _add_run_args(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("fit", help="fit sigma_Z = k Z^lambda to a recording")
    p.add_argument("recording")
    p.add_argument("--z-min", type=float, help="use only pixels with mean range >= this (m)")
    p.add_argument("--z-max", type=float, help="use only pixels with mean range <= this (m)")
    p.add_argument("--plot", help="write a sigma-vs-range PNG here")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--model", help="fit a composed model instead, e.g. active+slant_range+noise_floor")
    p.add_argument("--no-held-out", action="store_true", help="skip the leave-one-stop-out score (faster)")
    p.set_defaults(func=cmd_fit)

    p = sub.add_parser("compare", help="fit several models and show their errors side by side")
    p.add_argument("recording")
    p.add_argument("--models", required=True, help="comma-separated, e.g. active,active+slant_range")
    p.add_argument("--no-held-out", action="store_true", help="skip the leave-one-stop-out score (faster)")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("diagnose", help="where the model fails and which physical effect is most likely missing")
    p.add_argument("recording")
    p.add_argument("--model", help="model to start from (default: active with the projector on, passive without)")
    p.add_argument("--out", help="folder for the plots and the HTML report (default: RECORDING-diagnosis/)")
    p.set_defaults(func=cmd_diagnose)

    p = sub.add_parser("simulate", help="record a simulated experiment with a hidden effect (answer in OUT.answer.json)")
    p.add_argument("output")
    p.add_argument("--scenario", default="hidden")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--effect", help="hide this effect instead of the seed's choice (for validation)")
    p.add_argument("--width", type=int, default=106)
    p.add_argument("--frames", type=int, default=100)
    p.set_defaults(func=cmd_simulate)

    for name, help_text in (
        ("import", "turn folders of depth frames (16-bit PNG or .npy) into a recording (docs/import.md)"),
        ("devices", "list attached cameras and serial ports; --check CAMERA checks one"),
        ("tui", "the operator's terminal UI (docs/tui.md)"),
    ):
        p = sub.add_parser(name, help=help_text)
        p.add_argument("rest", nargs=argparse.REMAINDER)

    p = sub.add_parser("paper-windows", help="the paper's k/lambda-per-window table on simulated data")
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=cmd_paper_windows)

    p = sub.add_parser("validate-diagnosis", help="blind test of rig diagnose on hidden-effect simulations")
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("stage-sim", help="run a simulated stage controller on a pseudo-terminal (grbl or zaber)")
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=cmd_stage_sim)
    return parser


#: commands with their own argument parser: `rig NAME ARGS...` hands ARGS (and --help) to it
PASS_THROUGH = {"import": cmd_import, "devices": cmd_devices, "tui": cmd_tui, "stage-sim": cmd_stage_sim,
                "paper-windows": cmd_paper_windows, "validate-diagnosis": cmd_validate}


def main(argv: list[str] | None = None) -> int:
    from protocols.experiment_file import ExperimentFileError
    from protocols.runner import RunError

    from .importer import FolderImportError

    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in PASS_THROUGH:
        args = argparse.Namespace(func=PASS_THROUGH[argv[0]], rest=argv[1:])
    else:
        args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (UsageError, RunError, RecordingError, DeviceError, ExperimentFileError, FolderImportError) as e:
        print(f"rig: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rig: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
