"""The noise model file of a fit (`rig.noise-model/1`, docs/noise-model.md), as `rig export` writes it and the TUI's
export (e) does: the document (`rig.models.export`) with its headline error and the depth correction against the
stage, written whole, and the line that says what was written."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from protocols.recording import Recording

from ..accuracy import accuracy_of, bias_export
from ..diagnosis import Headline, headline
from ..models import ModelData, ModelFit
from ..models.export import noise_model_document
from .output_file import write_text


def default_model_path(recording: str | Path) -> Path:
    """Where `rig export RECORDING` writes when given no --out: RECORDING-noise-model.json beside it."""
    recording = Path(recording)
    return recording.with_name(recording.stem + "-noise-model.json")


def model_document(fit: ModelFit, d: ModelData, recording: str | Path, notes: list[str]) -> tuple[dict[str, Any], Headline]:
    """The document of `fit` (made on the pixels `d` of the recording at `recording`) and its headline error there;
    the bias is weighed as `rig fit` weighs the pixels (rig.accuracy.pixel_weights), so both give the same bias."""
    h = headline(fit, d)
    with Recording(recording) as rec:
        bias = bias_export(accuracy_of(d, None, rec.protocol, rec.protocol_params))
        return noise_model_document(fit, d, rec, recording, h, notes, bias), h


def write_model(doc: dict[str, Any], out: str | Path) -> Path:
    """Write the document to `out` (a folder that does not exist yet is made, as for every output), whole or not at
    all: a kill or a full disk leaves the previous model (rig.reports.output_file)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    return write_text(out, json.dumps(doc, indent=1) + "\n")


def written_line(doc: dict[str, Any], out: str | Path, h: Headline) -> str:
    """What was written, in one line: the file, the model, where sigma is valid and its headline error there."""
    z = doc["valid"]["z_m"]
    return (f"model: {out} ({doc['model']}; sigma valid for Z {z[0]:.3f}-{z[1]:.3f} m, headline error there "
            f"{h.error_pct:.2f} %)")
