"""A model parameter: its unit, bounds, starting value and whether it is fitted."""

from __future__ import annotations

from dataclasses import dataclass

@dataclass(frozen=True)
class Param:
    """A model parameter with its unit, bounds and starting value."""

    name: str
    value: float
    min: float
    max: float
    unit: str
    doc: str
    vary: bool = True
