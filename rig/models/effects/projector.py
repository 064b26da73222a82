"""Whether the data have what an effect on the projected light needs: frames with the projector on."""

from __future__ import annotations

from ..data.model_data import ModelData


def need_projector(d: ModelData, what: str) -> str | None:
    """None if some of `d`'s stops had the projector on, else why `what` cannot be fitted (one line)."""
    return None if d.projector_on.any() else f"{what} needs the projector on (it changes the projected light)"
