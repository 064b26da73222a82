"""Experiments described in TOML files, run with `rig run FILE.toml`.

    [experiment]
    protocol = "perpendicular"        # a protocol of the catalogue (protocols.catalogue)
    camera = "fake:width=424"         # device strings, as on the command line
    stage = "fake:"                   # default: the protocol's default_stage
    output = "perpendicular-active.h5"

    [parameters]                      # the protocol's parameters (its ProtocolSpec's, by name)
    stops_m = [0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0]
    frames_per_stop = 300
    projector_on = true
    exposure_us = 8500
    gain = 16

A parameter's old name (`frames` for frames_per_stop) is still read; files are written with the current names.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .catalogue import protocol_names, protocol_spec
from .plan import Plan
from .protocol_spec import ProtocolError


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
    """The protocol's plan for `params` (the others at their defaults); ExperimentFileError, one line, if the
    protocol is unknown, a parameter is not one of its own or a value is refused."""
    try:
        spec = protocol_spec(protocol)
        params = spec.current(params)
    except (ProtocolError, TypeError) as e:
        raise ExperimentFileError(f"{where}{e}") from None
    allowed = spec.names()
    unknown = [k for k in params if k not in allowed]
    if unknown:
        raise ExperimentFileError(f"{where}{protocol} has no parameter(s) {unknown}; it takes {allowed}")
    try:
        return spec.plan(**params)
    except (TypeError, ValueError) as e:
        raise ExperimentFileError(f"{where}{e}") from None


def load_experiment(path: str | Path) -> Experiment:
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ExperimentFileError(f"{path} does not exist; see examples/*.toml for experiment files") from None
    except (OSError, UnicodeDecodeError) as e:  # a folder, no permission, not text
        why = e.strerror if isinstance(e, OSError) and e.strerror else type(e).__name__
        raise ExperimentFileError(f"{path} cannot be read as an experiment file ({why}); give the path of a "
                                  ".toml file, e.g. examples/perpendicular-active.toml") from None
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
        choices = " or ".join(toml_value(n) for n in protocol_names())
        raise ExperimentFileError(f"{path}: [experiment] needs protocol = {choices}")
    if not isinstance(exp["protocol"], str):
        raise ExperimentFileError(f"{path}: [experiment] protocol = {exp['protocol']!r} must be a name in quotes, "
                                  f"one of {', '.join(protocol_names())}")
    plan = build_plan(exp["protocol"], data.get("parameters", {}), f"{path}: ")
    output = Path(exp["output"]) if "output" in exp else None
    if output is not None and not output.is_absolute():
        output = path.parent / output
    return Experiment(plan, exp.get("camera", "fake:"), exp.get("stage", protocol_spec(plan.name).default_stage), output, path)


def experiment_text(protocol: str, params: dict[str, Any], camera: str, stage: str, output: str | Path,
                    where: Path | None = None, header: str = "Run: rig run THIS-FILE.toml") -> str:
    """The TOML text of an experiment file that `load_experiment` reads back to the same plan.

    `output` is written relative to the file's folder (`where` is the file's path) when it can be.
    """
    build_plan(protocol, params)  # refuse to write a file `rig run` would refuse
    params = protocol_spec(protocol).current(params)  # old names written as the current ones
    out = Path(output)
    if where is not None and not out.is_absolute():
        out = Path(os.path.relpath(out.resolve(), where.resolve().parent))
    lines = [f"# {header}", "[experiment]", f"protocol = {toml_value(protocol)}", f"camera = {toml_value(camera)}",
             f"stage = {toml_value(stage)}", f"output = {toml_value(out.as_posix())}", "", "[parameters]"]
    lines += [f"{k} = {toml_value(v)}" for k, v in params.items()]
    return "\n".join(lines) + "\n"


def save_experiment(path: str | Path, protocol: str, params: dict[str, Any], camera: str, stage: str,
                    output: str | Path, header: str = "Run: rig run THIS-FILE.toml") -> Path:
    """Write an experiment file (see `experiment_text`)."""
    path = Path(path)
    text = experiment_text(protocol, params, camera, stage, output, path, header)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def toml_value(v: Any) -> str:
    """One value as TOML: booleans, numbers, strings and lists of them."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if v != v:
            return "nan"
        if v in (float("inf"), float("-inf")):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise ExperimentFileError(f"cannot write {v!r} to an experiment file")
