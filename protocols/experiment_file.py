"""Experiments described in TOML files, run with `rig run FILE.toml`.

    [experiment]
    protocol = "perpendicular"        # or "tilted"
    camera = "fake:width=424"         # device strings, as on the command line
    stage = "fake:"
    output = "perpendicular-active.h5"

    [parameters]                      # the protocol's parameters
    stops_m = [0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0]
    frames_per_stop = 300
    projector_on = true
    exposure_us = 8500
    gain = 16
"""

from __future__ import annotations

import inspect
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from . import PROTOCOLS
from .plan import Plan


class ExperimentFileError(ValueError):
    """The experiment file is invalid; the message names the file, the key and the fix."""


@dataclass
class Experiment:
    plan: Plan
    camera: str
    stage: str
    output: Path | None
    source: Path | None = None


def build_plan(protocol: str, params: dict[str, Any], where: str = "") -> Plan:
    if protocol not in PROTOCOLS:
        raise ExperimentFileError(f"{where}unknown protocol {protocol!r}; choose one of {', '.join(PROTOCOLS)}")
    fn = PROTOCOLS[protocol]
    allowed = list(inspect.signature(fn).parameters)
    unknown = [k for k in params if k not in allowed]
    if unknown:
        raise ExperimentFileError(f"{where}{protocol} has no parameter(s) {unknown}; it takes {allowed}")
    try:
        return fn(**params)
    except (TypeError, ValueError) as e:
        raise ExperimentFileError(f"{where}{e}") from None


def load_experiment(path: str | Path) -> Experiment:
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ExperimentFileError(f"{path} does not exist; see examples/*.toml for experiment files") from None
    except tomllib.TOMLDecodeError as e:
        raise ExperimentFileError(f"{path} is not valid TOML ({e}); fix the line it names") from None
    unknown = set(data) - {"experiment", "parameters"}
    if unknown:
        raise ExperimentFileError(f"{path}: unknown table(s) {sorted(unknown)}; use [experiment] and [parameters]")
    exp = data.get("experiment", {})
    unknown = set(exp) - {"protocol", "camera", "stage", "output"}
    if unknown:
        raise ExperimentFileError(f"{path}: [experiment] has unknown key(s) {sorted(unknown)}; it takes protocol, camera, stage, output")
    if "protocol" not in exp:
        raise ExperimentFileError(f"{path}: [experiment] needs protocol = \"perpendicular\" or \"tilted\"")
    plan = build_plan(exp["protocol"], data.get("parameters", {}), f"{path}: ")
    output = Path(exp["output"]) if "output" in exp else None
    if output is not None and not output.is_absolute():
        output = path.parent / output
    return Experiment(plan, exp.get("camera", "fake:"), exp.get("stage", "fake:" if plan.name == "perpendicular" else "none:"), output, path)
