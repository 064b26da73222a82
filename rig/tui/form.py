"""The experiment the operator is editing: a plain record that becomes a plan or a TOML file.

No Textual here. The plan is built by `protocols.experiment_file.build_plan` and files are read
by `load_experiment`, so the TUI accepts and writes exactly what `rig run FILE.toml` does.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocols.disk_space import free_bytes, size_text
from protocols.experiment_file import ExperimentFileError, build_plan, experiment_text, load_experiment, save_experiment
from protocols.perpendicular import DEFAULT_STOPS_M, perpendicular
from protocols.plan import Plan
from protocols.plan_check import RigLimits, disk_need_bytes, output_problems, plan_problems, stop_recipes, value_problem

DEFAULT_CAMERA = "fake:width=106,depth_unit_mm=0.05"
DEFAULT_STAGE = "fake:"

#: the parameters the form edits; any other parameter of a loaded file is kept as it was
FORM_PARAMS = {
    "perpendicular": ("stops_m", "frames_per_stop", "projector_on", "exposure_us", "gain"),
    "tilted": ("tilt_deg", "distance_m", "frames", "projector_on", "exposure_us", "gain"),
}


FIELDS = (  # id, label, input type, which protocol shows it ("" = both)
    ("stops", "Stops [m]", "text", "perpendicular"),
    ("tilt", "Tilt [deg]", "number", "tilted"),
    ("distance", "Distance [m]", "number", "tilted"),
    ("frames", "Frames per stop", "integer", ""),
    ("exposure", "Exposure [us]", "number", ""),
    ("gain", "Gain", "number", ""),
    ("output", "Output file", "text", ""),
)
LABELS = {wid: label for wid, label, _, _ in FIELDS}
#: what a field's characters may be (number fields: Textual's own rule for its type)
STOPS_CHARACTERS = r"[0-9.,:;eE+\- ]*"
#: the protocol parameter each number field sets
NUMBER_PARAMS = {"tilt": "tilt_deg", "distance": "distance_m", "exposure": "exposure_us", "gain": "gain"}


def field_problem(protocol: str, field: str, text: str, limits: RigLimits | None = None) -> str | None:
    """What is wrong with one field's text, by the rules `rig run` applies (`protocols.plan_check`), or None.
    Stops are checked against the stage's travel when `limits` knows it."""
    label, text = LABELS[field], text.strip()
    only = next(p for wid, _, _, p in FIELDS if wid == field)
    if only and only != protocol:
        return None
    if field == "output":
        problems = output_problems(Path(text)) if text else ["give a file name, e.g. run.h5"]
        return f"{label}: {problems[0]}" if problems else None
    if field == "stops":
        try:
            stops = parse_stops(text)
        except ExperimentFileError as e:
            return f"{label}: {e}"
        problem = value_problem(protocol, "stops_m", stops)
        if problem is None and limits is not None and limits.travel_m is not None:
            problem = next(iter(plan_problems(perpendicular(stops_m=stops), limits)), None)
        return None if problem is None else f"{label}: {_unprefixed(problem, protocol)}"
    whole = field == "frames"
    try:
        value = int(text) if whole else float(text)
    except ValueError:
        return f"{label}: {text!r} is not a {'whole ' if whole else ''}number" if text else f"{label}: give a number"
    param = ("frames" if protocol == "tilted" else "frames_per_stop") if whole else NUMBER_PARAMS[field]
    problem = value_problem(protocol, param, value)
    return None if problem is None else f"{label}: {_unprefixed(problem, protocol)}"


def _unprefixed(problem: str, protocol: str) -> str:
    """A protocol's message without the names the field's label already gives."""
    for prefix in (f"{protocol}: ", "capture settings: ", "stops_m: "):
        if problem.startswith(prefix):
            problem = problem[len(prefix):]
    return problem


@dataclass
class ExperimentSettings:
    """Everything the Experiment screen edits (device strings live on the Devices screen)."""

    protocol: str = "perpendicular"
    projector_on: bool = True
    stops_m: list[float] = field(default_factory=lambda: list(DEFAULT_STOPS_M))
    frames: int = 300
    tilt_deg: float = 31.0
    distance_m: float = 0.8
    exposure_us: float = 8500.0
    gain: float = 16.0
    output: str = "run.h5"
    extra: dict[str, Any] = field(default_factory=dict)  # other parameters of a loaded file, kept verbatim

    def params(self) -> dict[str, Any]:
        """The protocol's parameters, as `build_plan` and the [parameters] table take them."""
        common = {"projector_on": self.projector_on, "exposure_us": self.exposure_us, "gain": self.gain}
        if self.protocol == "tilted":
            own = {"tilt_deg": self.tilt_deg, "distance_m": self.distance_m, "frames": self.frames}
        else:
            own = {"stops_m": list(self.stops_m), "frames_per_stop": self.frames}
        return {**own, **common, **self.extra}

    def plan(self) -> Plan:
        """The plan; raises ExperimentFileError with a one-line message if a value is refused."""
        return build_plan(self.protocol, self.params())

    def problems(self, limits: RigLimits | None = None) -> list[str]:
        """Why the plan cannot finish on the rig `limits` describes (travel, output, disk); none: it can."""
        try:
            plan = self.plan()
        except ExperimentFileError as e:
            return [str(e)]
        out = Path(self.output)
        return plan_problems(plan, limits or RigLimits(), output=out, resume=out.exists())

    def disk_text(self, limits: RigLimits | None) -> str:
        """How much disk the run takes at most, when the camera's image size is known ("" if not)."""
        if limits is None or limits.image_shape is None:
            return ""
        out = Path(self.output)
        need = disk_need_bytes(stop_recipes(self.plan()), limits.image_shape, out, resume=out.exists())
        return f"up to {size_text(need)} on disk, {size_text(free_bytes(out.parent))} free"

    def device_geometry(self) -> dict[str, float]:
        """What `open_devices` needs to place a simulated wall for this protocol."""
        if self.protocol == "tilted":
            return {"tilt_deg": self.tilt_deg, "distance_m": self.distance_m}
        return {"tilt_deg": 0.0, "distance_m": 1.0}

    def describe(self) -> str:
        """One line: what the plan will do."""
        light = "projector on" if self.projector_on else "projector off"
        if self.protocol == "tilted":
            return f"tilted: wall at {self.distance_m:g} m tilted {self.tilt_deg:g} deg, {self.frames} frames, {light}"
        n = len(self.stops_m)
        span = f"{min(self.stops_m):.2f}-{max(self.stops_m):.2f} m" if n else "no stops"
        return f"perpendicular: {n} stops {span} x {self.frames} frames = {n * self.frames} frames, {light}"

    # -- files ------------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> tuple["ExperimentSettings", str, str]:
        """Read an experiment file as `rig run` does; return the settings, camera and stage strings."""
        exp = load_experiment(path)
        p = dict(exp.plan.params)
        own = FORM_PARAMS[exp.plan.name]
        s = cls(protocol=exp.plan.name)
        s.projector_on = bool(p["projector_on"])
        s.exposure_us = float(p["exposure_us"])
        s.gain = float(p["gain"])
        if exp.plan.name == "tilted":
            s.tilt_deg, s.distance_m, s.frames = float(p["tilt_deg"]), float(p["distance_m"]), int(p["frames"])
        else:
            s.stops_m, s.frames = [float(z) for z in p["stops_m"]], int(p["frames_per_stop"])
        defaults = build_plan(exp.plan.name, {}).params
        s.extra = {k: v for k, v in p.items() if k not in own and v != defaults.get(k)}
        s.output = _shorter(exp.output) if exp.output is not None else s.output
        return s, exp.camera, exp.stage

    def to_toml(self, camera: str, stage: str, where: Path | None = None) -> str:
        """The experiment file's text; `output` is written relative to the file's folder when it can be."""
        self.plan()  # refuse to write a file `rig run` would refuse, with the form's own message
        return experiment_text(self.protocol, self.params(), camera, stage, self.output, where,
                               header="Written by rig tui. Run: rig run THIS-FILE.toml")

    def save(self, path: str | Path, camera: str, stage: str) -> Path:
        self.plan()
        return save_experiment(path, self.protocol, self.params(), camera, stage, self.output,
                               header="Written by rig tui. Run: rig run THIS-FILE.toml")


def parse_stops(text: str) -> list[float]:
    """Distances in m: '0.5, 1.0, 1.5' or a range 'START:STOP:STEP' (inclusive), e.g. '0.5:3:0.25'."""
    text = text.strip()
    try:
        if ":" in text:
            parts = [float(x) for x in text.split(":")]
            if len(parts) != 3 or parts[2] <= 0 or parts[1] < parts[0]:
                raise ValueError
            start, stop, step = parts
            n = int(round((stop - start) / step))
            return [round(start + i * step, 6) for i in range(n + 1) if start + i * step <= stop + 1e-9]
        return [float(x) for x in text.replace(";", ",").split(",") if x.strip()]
    except ValueError:
        raise ExperimentFileError(f"stops {text!r}: write distances in m separated by commas (0.5, 1.0, 1.5) "
                                  "or a range START:STOP:STEP (0.5:3.0:0.25)") from None


def format_stops(stops: list[float]) -> str:
    return ", ".join(f"{z:g}" for z in stops)


def _shorter(path: Path) -> str:
    """A path relative to the working folder when it is inside it."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


