"""What a protocol is, as plain data: `ProtocolSpec`. Its name, its parameters (`ProtocolParam`: type, unit,
default, form label, check), the steps it makes from them, which parameter places its stops, how many frames
it takes at each stop, and what the rig needs for it (default stage, the wall's geometry).

    def steps(settings, *, distance_m, repeats, frames_per_stop):       # values already checked
        yield Home()
        yield Configure(settings.camera())
        yield Move(distance_m)
        for i in range(repeats):
            yield Settle(settings.settle_s)
            yield settings.capture(f"repeat-{i + 1}", frames_per_stop)

    REPEAT = ProtocolSpec("repeat", steps, params=(
        ProtocolParam("distance_m", float, 1.0, "m", "Distance [m]", "camera to wall", distance_m),
        ProtocolParam("repeats", int, 3, "", "Repeats", "captures at the one distance", whole_between(1, 100))),
        stops_param="distance_m", frames_per_stop=100)

Every protocol takes `frames_per_stop` (one name, `FRAMES_PER_STOP`: `rig run --frames`) and the capture
settings (`capture_settings.CAPTURE_PARAMS`) after its own parameters; a plan records them all, in that order.
`protocols.catalogue` registers specs; `rig run`'s options, experiment files and the TUI's form are made from it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Mapping

from .capture_settings import CAPTURE_PARAMS, CaptureSettings
from .plan import Plan, Step
from .plan_values import TYPES, ProtocolParam, frames

#: the one name of the frames captured at each stop, in every protocol
FRAMES_PER_STOP = "frames_per_stop"
#: what places the wall before the camera: a simulated camera builds its wall from these (rig.devices.open_devices)
WALL_KEYS = ("tilt_deg", "distance_m")
NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]*")
PARAM_NAME = re.compile(r"[a-z][a-z0-9_]*")
OPTION = re.compile(r"--[a-z][a-z0-9-]*")


class ProtocolError(ValueError):
    """A protocol that cannot be registered or found; the message names it and the fix."""


def frames_param(default: int) -> ProtocolParam:
    """The frames parameter every protocol takes (only its default differs)."""
    return ProtocolParam(FRAMES_PER_STOP, int, default, "", "Frames per stop",
                         "frames captured at each stop (a variance needs at least 2)", frames, option="--frames",
                         old_names=("frames",))


@dataclass(frozen=True, eq=False)
class ProtocolSpec:
    """One protocol, described once.

    name: what experiment files, `rig run --protocol` and the TUI call it; steps: (settings, **values) -> the
    plan's steps, given the capture settings and every other parameter's checked value by name; params: its own
    parameters (frames_per_stop and the capture settings come with every protocol); stops_param: the parameter
    that places the stops (errors about a stop's position name it; a resumed run may change it);
    frames_per_stop: its default frames at each stop; default_stage: the stage string when none is given;
    wall: WALL_KEYS to the parameters that give them (a tilted wall: {"tilt_deg": "tilt_deg", ...}); summary:
    one line for help texts.
    """

    name: str
    steps: Callable[..., Iterator[Step]]
    params: tuple[ProtocolParam, ...] = ()
    stops_param: str = ""
    frames_per_stop: int = 300
    default_stage: str = "fake:"
    wall: Mapping[str, str] = field(default_factory=dict)
    summary: str = ""

    def all_params(self) -> tuple[ProtocolParam, ...]:
        """Every parameter, in the order a plan records them: its own, frames_per_stop, the capture settings."""
        return (*self.params, frames_param(self.frames_per_stop), *CAPTURE_PARAMS)

    def names(self) -> list[str]:
        return [p.name for p in self.all_params()]

    def param(self, name: str) -> ProtocolParam | None:
        return next((p for p in self.all_params() if p.name == name), None)

    def current(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """`params` with old names (`ProtocolParam.old_names`) read as the current ones; TypeError if both are given."""
        out = dict(params)
        for p in self.all_params():
            for old in p.old_names:
                if old in out:
                    if p.name in out:
                        raise TypeError(f"{self.name}: {old} is the old name of {p.name}; give {p.name} only")
                    out[p.name] = out.pop(old)
        return out

    def plan(self, **given: Any) -> Plan:
        """The plan for these parameters (the others at their defaults), every value checked: a ValueError names
        the parameter and its range, a TypeError a name the protocol does not take."""
        given = self.current(given)
        names = self.names()
        unknown = [k for k in given if k not in names]
        if unknown:
            raise TypeError(f"{self.name}() got unexpected keyword argument(s) {unknown}; it takes {names}")
        capture = {p.name for p in CAPTURE_PARAMS}
        settings = CaptureSettings(**{k: v for k, v in given.items() if k in capture})
        values = {p.name: p.checked(self.name, given.get(p.name, p.default))
                  for p in self.all_params() if p.name not in capture}
        steps = self.steps
        return Plan(self.name, {**values, **settings.to_params()}, lambda: steps(settings, **values),
                    stops_param=self.stops_param)

    def wall_of(self, params: Mapping[str, Any]) -> dict[str, float]:
        """The wall's geometry for a plan's parameters, by WALL_KEYS (none: the rig's default wall)."""
        return {key: params[name] for key, name in self.wall.items() if name in params}

    def problems(self) -> list[str]:
        """What is wrong with the spec itself (none: it can be registered)."""
        out = []
        if not isinstance(self.name, str) or not NAME.fullmatch(self.name):
            out.append(f"name {self.name!r} must be letters, digits, - and _, starting with a letter")
        if not callable(self.steps):
            out.append("steps must be a function (settings, **values) -> steps")
        own = [p.name for p in self.params]
        shared = [p.name for p in self.all_params()[len(self.params):]]
        for p in self.params:
            if not isinstance(p, ProtocolParam):
                out.append(f"{p!r} is not a ProtocolParam")
                return out
            if not PARAM_NAME.fullmatch(p.name):
                out.append(f"parameter {p.name!r} must be lower-case letters, digits and _, starting with a letter")
            if p.name in shared:
                out.append(f"parameter {p.name} is one every protocol takes already; leave it out of params")
            if own.count(p.name) > 1:
                out.append(f"parameter {p.name} is given twice")
            if p.type not in TYPES:
                out.append(f"parameter {p.name}: type {p.type!r} is not one of float, int, bool, list")
            if p.option and not OPTION.fullmatch(p.option):
                out.append(f"parameter {p.name}: option {p.option!r} must be --lower-case-words")
        names = own + shared
        for p in self.all_params():
            taken = [o for o in p.old_names if o in names]
            if taken:
                out.append(f"parameter {p.name}: old name(s) {taken} are parameters now")
        if self.stops_param and self.stops_param not in own:
            out.append(f"stops_param {self.stops_param!r} is not one of its parameters {own}")
        for key, name in self.wall.items():
            if key not in WALL_KEYS or name not in own:
                out.append(f"wall {key!r}: {name!r} must map one of {list(WALL_KEYS)} to one of its parameters")
        if not isinstance(self.default_stage, str) or not self.default_stage:
            out.append("default_stage must be a stage string, e.g. 'fake:' or 'none:'")
        if not out:
            try:
                self.plan()
            except (TypeError, ValueError) as e:
                out.append(f"its defaults are refused ({e})")
        return out
