"""The experiment the operator is editing: a plain record that becomes a plan or a TOML file.

No Textual here. The form's fields are made from the protocol catalogue (`protocols.catalogue`): one field for
each parameter name a protocol shows on the form (`ProtocolParam.form`), shown while a protocol that takes it
is selected, with that protocol's label. The plan is built by `protocols.experiment_file.build_plan` and files
are read by `load_experiment`, so the TUI accepts and writes exactly what `rig run FILE.toml` does; a field's
text is read by the parameter's own parser, the one `rig run`'s options use.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocols.catalogue import catalogue_params, protocol_names, protocol_spec
from protocols.disk_space import free_bytes, size_text
from protocols.experiment_file import ExperimentFileError, build_plan, experiment_text, load_experiment, save_experiment
from protocols.plan import Plan
from protocols.plan_check import RigLimits, disk_need_bytes, output_problems, plan_problems, stop_recipes, value_problem
from protocols.plan_values import ProtocolParam
from protocols.protocol_spec import ProtocolSpec

DEFAULT_CAMERA = "fake:width=106,depth_unit_mm=0.05"
DEFAULT_STAGE = "fake:"
#: the field of the output file (every protocol has one)
OUTPUT = "output"
#: what a list field's characters may be (number fields: Textual's own rule for its type)
LIST_CHARACTERS = r"[0-9.,:;eE+\- ]*"


@dataclass(frozen=True)
class FormField:
    """One field of the form: `id` is the widget's id (its `rig run` option without the dashes: --stops ->
    stops), `name` the parameter's, `kind` the widget ("checkbox", or an Input's type: "number", "integer",
    "text"), `protocols` the protocols that take it (all: the output file)."""

    id: str
    name: str
    kind: str
    protocols: tuple[str, ...]
    restrict: str | None = None


def form_fields() -> list[FormField]:
    """The form's fields, from the catalogue: check boxes first, then each protocol's own parameters, the frames
    and the capture settings, then the output file."""
    out = []
    for name, uses in catalogue_params().items():
        shown = tuple(spec.name for spec, p in uses if p.form)
        if not shown:
            continue
        p = uses[0][1]
        kind = {bool: "checkbox", float: "number", int: "integer"}.get(p.type, "text")
        out.append(FormField(p.cli_option.lstrip("-"), name, kind, shown, LIST_CHARACTERS if p.type is list else None))
    out.sort(key=lambda f: f.kind != "checkbox")
    return out + [FormField(OUTPUT, OUTPUT, "text", tuple(protocol_names()))]


def form_field(wid: str) -> FormField:
    return next(f for f in form_fields() if f.id == wid)


def field_param(protocol: str, wid: str) -> ProtocolParam | None:
    """The protocol's parameter a field sets (None: the protocol does not take it, or the output file)."""
    f = form_field(wid)
    return protocol_spec(protocol).param(f.name) if protocol in f.protocols and f.id != OUTPUT else None


def field_label(protocol: str, wid: str) -> str:
    """A field's label while `protocol` is selected (its parameter's label there)."""
    if wid == OUTPUT:
        return "Output file"
    param = field_param(protocol, wid)
    if param is None:  # not shown: the label of a protocol that takes it
        f = form_field(wid)
        param = protocol_spec(f.protocols[0]).param(f.name)
    return param.form_label


def field_takes(protocol: str, wid: str) -> str:
    """What a field takes, in words (said when a character is refused)."""
    param = field_param(protocol, wid)
    if param is None:
        return "text"
    return param.takes() + (": digits , . : only" if param.type is list else "")


def field_problem(protocol: str, field: str, text: str, limits: RigLimits | None = None) -> str | None:
    """What is wrong with one field's text, by the rules `rig run` applies (`protocols.plan_check`), or None.
    The protocol's stops are checked against the stage's travel when `limits` knows it."""
    label, text = field_label(protocol, field), text.strip()
    if field == OUTPUT:
        problems = output_problems(Path(text)) if text else ["give a file name, e.g. run.h5"]
        return f"{label}: {problems[0]}" if problems else None
    param = field_param(protocol, field)
    if param is None:
        return None
    try:
        value = param.parse(text)
    except ValueError as e:
        return f"{label}: {e}"
    problem = value_problem(protocol, param.name, value)
    spec = protocol_spec(protocol)
    if problem is None and param.name == spec.stops_param and limits is not None and limits.travel_m is not None:
        problem = next(iter(plan_problems(spec.plan(**{param.name: value}), limits)), None)
    return None if problem is None else f"{label}: {_unprefixed(problem, protocol, param.name)}"


def _unprefixed(problem: str, protocol: str, name: str) -> str:
    """A protocol's message without the names the field's label already gives."""
    for prefix in (f"{protocol}: ", "capture settings: ", f"{name}: "):
        if problem.startswith(prefix):
            problem = problem[len(prefix):]
    return problem


@dataclass
class ExperimentSettings:
    """Everything the Experiment screen edits (device strings live on the Devices screen).

    values: the form's parameters by name (any the protocol takes but `values` lacks: the protocol's default);
    extra: other parameters of a loaded file, kept verbatim.
    """

    protocol: str = field(default_factory=lambda: protocol_names()[0])
    values: dict[str, Any] = field(default_factory=dict)
    output: str = "run.h5"
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def spec(self) -> ProtocolSpec:
        return protocol_spec(self.protocol)

    def value(self, name: str) -> Any:
        """A parameter's value: as set, else the protocol's default (or that of one that takes it)."""
        if name in self.values:
            return self.values[name]
        param = self.spec.param(name) or next(p for _, p in catalogue_params()[name])
        return param.default

    def params(self) -> dict[str, Any]:
        """The protocol's parameters, as `build_plan` and the [parameters] table take them."""
        return {**{p.name: self.value(p.name) for p in self.spec.all_params() if p.form}, **self.extra}

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
        """What `open_devices` needs to place a simulated wall for this protocol (`ProtocolSpec.wall`)."""
        return self.spec.wall_of(self.plan().params)

    def describe(self) -> str:
        """One line: what the plan will do."""
        return describe_plan(self.plan(), self.spec)

    # -- files ------------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> tuple["ExperimentSettings", str, str]:
        """Read an experiment file as `rig run` does; return the settings, camera and stage strings."""
        exp = load_experiment(path)
        p, spec = dict(exp.plan.params), protocol_spec(exp.plan.name)
        shown = {q.name for q in spec.all_params() if q.form}
        defaults = build_plan(spec.name, {}).params
        s = cls(protocol=spec.name, values={k: v for k, v in p.items() if k in shown},
                extra={k: v for k, v in p.items() if k not in shown and v != defaults.get(k)})
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


def describe_plan(plan: Plan, spec: ProtocolSpec) -> str:
    """One line: the stops, the frames and the light, e.g. 'perpendicular: 11 stops 0.50-3.00 m x 300 frames =
    3300 frames, projector on'; then the protocol's other own parameters ('; tilt_deg 31')."""
    recipes = list(stop_recipes(plan).values())
    n, frames = len(recipes), [r.capture.n_frames for r in recipes]
    at = sorted(r.position_m for r in recipes if r.position_m is not None)
    span = "" if not at else f" at {at[0]:.2f} m" if at[0] == at[-1] else f" {at[0]:.2f}-{at[-1]:.2f} m"
    count = f"x {frames[0]} frames = {sum(frames)} frames" if len(set(frames)) == 1 else f"{sum(frames)} frames"
    light = "projector on" if plan.params.get("projector_on", True) else "projector off"
    others = [f"{p.name} {p.text(plan.params[p.name])}" for p in spec.params if p.name != spec.stops_param]
    return (f"{plan.name}: {n} stop{'s' * (n != 1)}{span} {count}, {light}" if n else f"{plan.name}: no stops") + \
        "".join(f"; {o}" for o in others)


def _shorter(path: Path) -> str:
    """A path relative to the working folder when it is inside it."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)
