"""Experiments: plans (what happens) and the runner (how it happens to devices and files).

    from protocols import perpendicular, Runner
    plan = perpendicular(frames_per_stop=300, projector_on=True)
    Runner(camera, stage).run(plan, "run.h5")

Everything an acquisition needs lives here: the protocols (`catalogue`: each one's `ProtocolSpec`) and their
capture settings, the runner, the streaming statistics (`stats`), the recording format (`recording`),
experiment files and the import of folders of frames. It imports only `drivers`.

The other names below are imported when first used, so that reading the catalogue (`rig --help` lists the
protocols' options) does not load the runner and its compiled statistics. `perpendicular` and `tilted` are
imported now: they are also the names of their modules, which would otherwise take their place here.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from .perpendicular import perpendicular
from .tilted import tilted

_WHERE = {
    "PROTOCOLS": "catalogue", "register_protocol": "catalogue",
    "ProtocolSpec": "protocol_spec", "ProtocolParam": "plan_values", "CaptureSettings": "capture_settings",
    "Plan": "plan", "Capture": "plan", "Configure": "plan", "Home": "plan", "Move": "plan", "Settle": "plan",
    "Runner": "runner", "RunError": "run_errors", "RunResult": "runner",
}
__all__ = ["perpendicular", "tilted", *_WHERE]

if TYPE_CHECKING:  # for type checkers; at run time __getattr__ imports each name when first used
    from .capture_settings import CaptureSettings
    from .catalogue import PROTOCOLS, register_protocol
    from .plan import Capture, Configure, Home, Move, Plan, Settle
    from .plan_values import ProtocolParam
    from .protocol_spec import ProtocolSpec
    from .run_errors import RunError
    from .runner import Runner, RunResult


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'protocols' has no attribute {name!r}")
    value = getattr(import_module(f".{_WHERE[name]}", __name__), name)
    globals()[name] = value
    return value
