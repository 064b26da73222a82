"""Models from text, as the command line takes them: "active+slant_range+noise_floor"."""

from __future__ import annotations

from .catalogue import Catalogue
from .composition import Model


def parse_model(text: str, catalogue: Catalogue | None = None) -> Model:
    """'active+slant_range+noise_floor' -> Model, with the effects of `catalogue` (default: the built-in ones)."""
    return (catalogue or Catalogue.builtin()).parse(text)
