"""One model fitted to each of several recordings, as plain data: what `rig compare a.h5 b.h5` and
`rig repeatability` compare, and what a worker process or a Dask worker sends back (`rig.fleet.many.fit_for_comparison`,
`rig.fleet.executors`).

The model is the same for every recording, except its base where the projector says otherwise: `active` (lambda
= 3) on a recording made with the projector off becomes `passive` (lambda = 2) there, and the other way round,
with a note; the comparison then covers the parameters both fits have (k, and the effects' own).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..accuracy.bias import UNITS
from ..accuracy.summary import accuracy_of
from ..models import parse_model
from ..models.export import noise_model_document
from ..noise_model import NoiseModel, NoiseModelError
from .camera_setup import read_setup

#: the model fitted when none is given: the paper's k Z^lambda, both free
PAPER = "power_law"


@dataclass(frozen=True)
class FitJob:
    """What a worker needs to fit one recording: its path, the model (None: the paper's fit, as `rig fit`), and the
    files of the user's effects the model may name."""

    path: str
    model: str | None = None
    effects: tuple[str, ...] = ()
    z_min_m: float | None = None  # the window of ranges fitted (--z-min, --z-max), m
    z_max_m: float | None = None


@dataclass
class RecordingResult:
    """One recording's fit, or why it has none (`error`)."""

    path: str
    model: str = ""
    projector_on: bool = True
    values: dict[str, float] = field(default_factory=dict)
    errors: dict[str, float] = field(default_factory=dict)  # Cramer-Rao, of the free parameters
    free: list[str] = field(default_factory=list)
    units: dict[str, str] = field(default_factory=dict)
    n_obs: int = 0
    headline_pct: float = float("nan")
    noise_pct: float = float("nan")
    verdict: str = ""
    z_m: list[float] = field(default_factory=list)  # measured sigma per stop (or 0.25 m window): range, m
    sigma_m: list[float] = field(default_factory=list)
    se_sigma_m: list[float] = field(default_factory=list)
    curve_z_m: list[float] = field(default_factory=list)  # the model's sigma on the optical axis, for plots
    curve_sigma_m: list[float] = field(default_factory=list)
    curve_label: str = ""
    notes: list[str] = field(default_factory=list)
    started_utc: str = ""
    camera: str = ""
    error: str = ""
    setup: dict[str, object] = field(default_factory=dict)  # what it was made with (`rig.recordings.camera_setup`)

    @property
    def name(self) -> str:
        return Path(self.path).name


def model_for(spec: str, projector_on: bool, catalogue=None):
    """(the model `spec` names, with its base matched to the projector, a note if it was changed)."""

    model = parse_model(spec, catalogue)
    base = model.base.name
    swap = {"active": "passive", "passive": "active"}
    if base in swap and (base == "active") != projector_on:
        other = parse_model(spec.replace(base, swap[base], 1), catalogue)
        return other, (f"the projector was {'on' if projector_on else 'off'}: fitted {other.name} (lambda = "
                       f"{other.base.lam:g}) instead of {model.name}")
    return model, None


def summarise(path: str, fit, d, h, measured, rec, notes: list[str], projector_on: bool) -> RecordingResult:
    """A fit as plain data: `fit` of the pixels `d` of the open recording `rec` at `path`, its headline `h` and the
    measured sigma per stop (`measured`, a BinnedSigma)."""
    started = str(rec.attrs.get("started_utc", ""))
    camera = f"{rec.attrs.get('camera_model', '')} {rec.attrs.get('camera_serial', '')}".strip()
    z, sigma, label = axis_curve(fit, d, rec, measured.z_m)
    values = {k: float(v) for k, v in fit.values.items()}
    errors = {n: float(fit.errors.get(n, float("nan"))) for n, _ in fit.model.free()}
    free = [n for n, _ in fit.model.free()]
    units = {n: p.unit for n, p in fit.model.parameters()}
    bias = accuracy_of(d, None, rec.protocol, rec.protocol_params).bias  # as rig fit and rig export weigh the pixels
    if bias is not None:  # the calibration bias against the stage: compared and scattered as the noise's parameters
        for n in bias.names:
            values[f"bias.{n}"], errors[f"bias.{n}"], units[f"bias.{n}"] = bias.values[n], bias.errors[n], UNITS[n]
            free.append(f"bias.{n}")
    return RecordingResult(
        str(path), fit.model.name, projector_on, values, errors, free, units, int(fit.n_obs), float(h.error_pct),
        float(h.noise_pct),
        h.verdict(), [float(x) for x in measured.z_m], [float(x) for x in measured.sigma_m],
        [float(x) for x in measured.se_sigma_m], z, sigma, label, list(notes), started, camera, setup=read_setup(rec))


def axis_curve(fit, d, rec, z_measured) -> tuple[list[float], list[float], str]:
    """The model's sigma on the optical axis over the measured ranges (`rig.noise_model`, as exported); the base
    k Z^lambda alone where a term needs a measured input (brightness, ambient light, drift)."""

    z = np.linspace(min(z_measured) * 0.95, max(z_measured) * 1.03, 120)
    try:
        m = NoiseModel.from_dict(noise_model_document(fit, d, rec, ""))
        cal = d.calibration
        extra = {"cos_incidence": np.ones_like(z)} if "cos_incidence" in m.inputs else {}
        sigma = m.sigma(z, cal.cx, cal.cy, **extra)
        label = "on axis"
    except NoiseModelError:
        sigma = fit.k * z**fit.lam
        label = "k Z^lambda only"
    return [float(x) for x in z], [float(x) for x in sigma], label
