"""The protocols by name: `rig run`'s options and --protocol choices, experiment files and the TUI's form are
made from here, so a protocol's spec (`protocol_spec.ProtocolSpec`) is the one place that names it.

The built-in protocols are `BUILT_IN`; installed packages add theirs under the entry-point group
`rig.protocols` (a ProtocolSpec, or a list of them); a script or a test adds one with `register_protocol(spec)`.
A parameter name means one thing in the whole catalogue: protocols that share a name share its type, its
option and its old names, so the command line and the form have one field for it.
"""

from __future__ import annotations

from importlib.metadata import entry_points
from typing import Any, Callable, Iterator, Mapping

from .perpendicular import PERPENDICULAR
from .plan import Plan
from .plan_values import ProtocolParam
from .protocol_spec import ProtocolError, ProtocolSpec
from .tilted import TILTED

ENTRY_POINT_GROUP = "rig.protocols"
BUILT_IN = (PERPENDICULAR, TILTED)

_specs: dict[str, ProtocolSpec] = {}
_sources: dict[str, str] = {}
_plugin_problems: list[str] = []
_plugins_loaded = False


def register_protocol(spec: ProtocolSpec, source: str = "registered at run time") -> ProtocolSpec:
    """Add `spec` to the catalogue; a ProtocolError (one line) if it is malformed, its name is taken or a
    parameter it shares by name with another protocol means something else there."""
    if not isinstance(spec, ProtocolSpec):
        raise ProtocolError(f"{spec!r} ({source}) is not a ProtocolSpec")
    problems = spec.problems()
    if spec.name in _specs:
        problems.insert(0, f"the name is taken by the protocol from {_sources[spec.name]}; rename it")
    known = _params_of(_specs.values())
    for name, uses in known.items():
        mine = spec.param(name)
        theirs = uses[0][1]
        if mine is not None and _meaning(mine) != _meaning(theirs):
            problems.append(f"parameter {name} is {_meaning(mine)} here but {_meaning(theirs)} in {uses[0][0].name}; "
                            "give it another name or the same type, option and old names")
    options = {uses[0][1].cli_option: name for name, uses in known.items()}
    for p in spec.all_params():
        if options.setdefault(p.cli_option, p.name) != p.name:
            problems.append(f"parameter {p.name}: option {p.cli_option} is {options[p.cli_option]}'s already")
    if problems:
        raise ProtocolError(f"protocol {spec.name!r} ({source}) cannot be registered: {'; '.join(problems)}")
    _specs[spec.name], _sources[spec.name] = spec, source
    return spec


def unregister_protocol(name: str) -> None:
    """Take a protocol out of the catalogue (a test's own, when it ends)."""
    _specs.pop(name, None)
    _sources.pop(name, None)


def _meaning(p: ProtocolParam) -> str:
    """What must be the same wherever a parameter name is used, in words."""
    old = f", once {' and '.join(p.old_names)}" if p.old_names else ""
    return f"{p.type.__name__} ({p.cli_option}{old})"


def _load_plugins() -> None:
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            loaded = ep.load()
            for spec in loaded if isinstance(loaded, (list, tuple)) else [loaded]:
                register_protocol(spec, f"entry point {ep.name}")
        except Exception as e:  # a broken plugin leaves the other protocols usable, and is named where it is missed
            _plugin_problems.append(f"the protocol plugin {ep.name} ({ep.value}) failed to load "
                                    f"({type(e).__name__}: {e}); reinstall or remove the package that provides it")


def protocol_specs() -> dict[str, ProtocolSpec]:
    """Every protocol by name, in catalogue order: built-in, installed plugins', registered."""
    _load_plugins()
    return dict(_specs)


def protocol_names() -> list[str]:
    return list(protocol_specs())


def protocol_spec(name: str) -> ProtocolSpec:
    """The protocol called `name`; ProtocolError naming the ones there are."""
    specs = protocol_specs()
    if name not in specs:
        why = "".join(f"; {p}" for p in _plugin_problems)
        raise ProtocolError(f"unknown protocol {name!r}; choose one of {', '.join(specs)}{why}")
    return specs[name]


def parameters(protocol: str) -> list[str]:
    """Every parameter of a protocol: its own (stops, geometry), frames_per_stop, then the capture settings."""
    return protocol_spec(protocol).names()


def catalogue_params() -> dict[str, list[tuple[ProtocolSpec, ProtocolParam]]]:
    """Every parameter name of the catalogue with the protocols that take it (and their entry for it): each
    protocol's own parameters first, in catalogue order, then frames_per_stop and the capture settings."""
    return _params_of(protocol_specs().values())


def _params_of(specs) -> dict[str, list[tuple[ProtocolSpec, ProtocolParam]]]:
    own: dict[str, list] = {}
    shared: dict[str, list] = {}
    for spec in specs:
        for i, p in enumerate(spec.all_params()):
            (own if i < len(spec.params) else shared).setdefault(p.name, []).append((spec, p))
    return {**own, **{k: v for k, v in shared.items() if k not in own}}


def current_params(params: Mapping[str, Any]) -> dict[str, Any]:
    """Parameters written under a name the catalogue has since renamed (a recording's stored plan, an old
    experiment file), under the current name. Old names mean one thing in the whole catalogue (`register_protocol`
    sees to it), so this needs no protocol."""
    if not isinstance(params, Mapping):
        return params  # not a table of parameters: left for the caller's own check
    renamed = {old: name for name, uses in catalogue_params().items() for old in uses[0][1].old_names}
    out = dict(params)
    for old, name in renamed.items():
        if old in out and name not in out:
            out[name] = out.pop(old)
    return out


class _Plans(Mapping[str, Callable[..., Plan]]):
    """Each protocol's plan function by name (`PROTOCOLS["perpendicular"](stops_m=[1.0])`), kept in step with
    the catalogue."""

    def __getitem__(self, name: str) -> Callable[..., Plan]:
        return protocol_specs()[name].plan

    def __iter__(self) -> Iterator[str]:
        return iter(protocol_specs())

    def __len__(self) -> int:
        return len(protocol_specs())


PROTOCOLS: Mapping[str, Callable[..., Plan]] = _Plans()

for _spec in BUILT_IN:
    register_protocol(_spec, "built-in")
