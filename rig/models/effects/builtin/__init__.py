"""The built-in effects, one module each: a module in this folder is an effect of the catalogue.

Importing this package imports every module in it (`discover`); each registers its effect with `@register`
(`rig.models.parts.component`), which puts it in `EFFECTS`, ordered by the effects' `position`. An effect's module
holds its physics (`apply`), its derivatives (`apply_tangent`), the name of its twin in the simulator (`twin`,
an effect of fakes/effects.py) and the parameters the blind test hides for it (`scenario`). To add an effect, add
a module here (docs/architecture.md); nothing else to edit.
"""

from __future__ import annotations

import importlib
import pkgutil

from ...parts.component import EFFECTS, order_builtins


def discover() -> list[str]:
    """Import every module of this package not imported yet (a module named with a leading _ is not an effect),
    then order the catalogue by position; the modules' names, in the order found."""
    names = sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))
    for name in names:
        importlib.import_module(f"{__name__}.{name}")
    order_builtins()
    return names


discover()

__all__ = ["EFFECTS", "discover"]
