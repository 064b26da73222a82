"""The protocols by name, and the parameters each takes (what an experiment file's [parameters] may set)."""

from __future__ import annotations

import inspect
from typing import Callable

from .capture_settings import CaptureSettings
from .perpendicular import perpendicular
from .plan import Plan
from .tilted import tilted

PROTOCOLS: dict[str, Callable[..., Plan]] = {"perpendicular": perpendicular, "tilted": tilted}


def parameters(protocol: str) -> list[str]:
    """Every parameter of a protocol: its own (stops, frames, geometry), then the capture settings."""
    own = [p.name for p in inspect.signature(PROTOCOLS[protocol]).parameters.values() if p.kind is not p.VAR_KEYWORD]
    return own + CaptureSettings.names()
