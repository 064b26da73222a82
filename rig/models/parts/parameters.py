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

    def at_bound(self, v: float) -> str | None:
        """"lower" or "upper" when the value `v` sits at that bound (within 1e-6 of it, relative where it is
        large), else None: a fit there is on the edge of what the parameter may take."""
        if abs(v - self.min) < 1e-6 * max(1.0, abs(self.min)):
            return "lower"
        if abs(v - self.max) < 1e-6 * max(1.0, abs(self.max)):
            return "upper"
        return None
