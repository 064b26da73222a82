"""Models from text, as the command line takes them: "active+slant_range+noise_floor"."""

from __future__ import annotations

from .bases import BASES
from .composition import Model
from .effects import EFFECTS


def parse_model(text: str) -> Model:
    """'active+slant_range+noise_floor' -> Model."""
    parts = [p.strip() for p in text.replace(" ", "").split("+") if p.strip()]
    if not parts or parts[0] not in BASES:
        raise ValueError(f"model {text!r} must start with a base model ({', '.join(BASES)}), e.g. active+slant_range")
    m = Model(BASES[parts[0]])
    for name in parts[1:]:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r} in model {text!r}; effects: {', '.join(EFFECTS)}")
        m = m + EFFECTS[name]
    return m
