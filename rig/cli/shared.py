"""What the analysis commands share (fit, compare, diagnose, export, repeatability): their common options, the
catalogue of effects, reading a recording into a model's data, parsing a model, the progress line."""

from __future__ import annotations

import argparse
import os

from .options import at_least, verbosity
from .usage import UsageError


def shared_options(several: bool = False) -> argparse.ArgumentParser:
    """What fit, compare and diagnose all take: the recording (with `several`, one or more, or folders of them),
    --json, --effects and --jobs."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("recording", nargs="+" if several else None)
    p.add_argument("--json", action="store_true", help="print the result as JSON (docs/json.md)")
    p.add_argument("--effects", action="append", default=[], metavar="FILE.py",
                   help="load effects you wrote (a Python file of @register classes; docs/effects.md); may be repeated")
    p.add_argument("--jobs", type=at_least(1, "processes"), default=os.cpu_count() or 1,
                   help="processes for the work that runs in parallel: the held-out score's refits, --many, the "
                        "diagnosis's candidate effects (default: one per core)")
    return p


def window_options() -> argparse.ArgumentParser:
    """The window of ranges to fit (fit, compare): --z-min, --z-max, in metres."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--z-min", type=float, metavar="M", help="use only pixels with mean range >= this (m)")
    p.add_argument("--z-max", type=float, metavar="M", help="use only pixels with mean range <= this (m)")
    return p


def catalogue_of(args: argparse.Namespace):
    """The built-in effects, installed plugins' and those of every --effects file."""
    from ..models import Catalogue

    cat = Catalogue.default()
    for path in getattr(args, "effects", []) or []:
        cat = cat.with_file(path)
    return cat


def model_data(path: str, z_min: float | None = None, z_max: float | None = None):
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


def check_window(args: argparse.Namespace) -> None:
    """Refuse a --z-min/--z-max window that can hold no pixel, before the recording is read."""
    from ..analysis import check_window

    try:
        check_window(getattr(args, "z_min", None), getattr(args, "z_max", None))
    except ValueError as e:
        raise UsageError(str(e)) from None


def parse_model_option(text: str, catalogue=None):
    from ..models import parse_model

    try:
        return parse_model(text, catalogue)
    except ValueError as e:
        raise UsageError(str(e)) from None


def fit_or_refuse(model, d):
    """`model` fitted to `d`; a model the data cannot take (rig.models: a ValueError) is the one-line usage error."""
    try:
        return model.fit(d)
    except ValueError as e:
        raise UsageError(str(e)) from None


def progress_line(args: argparse.Namespace, title: str):
    """The terminal's progress line for this command (silent when stderr is not a terminal, or with -q)."""
    from ..reports.work_progress import WorkProgressLine

    return WorkProgressLine(title, verbosity(args))
