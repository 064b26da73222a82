"""Effects written as a per-pixel term of the covariates, in a short Python file: they compose, fit and rank like
the built-in ones, and are classes registered the same way.

    from rig.models import Param, TermEffect, register

    @register
    class BeamFalloff(TermEffect):
        '''The projector's beam falls off as cos^n of the off-axis angle.'''

        name = "beam_falloff"
        stage = "illumination"
        params = (Param("n", 2.0, 0.0, 12.0, "1", "exponent of the beam's cos^n fall-off"),)
        signature = "the error grows towards the image corners faster than slant range explains"

        def term(self, c, n):
            return c.cos_off_axis ** -n          # the shot-noise variance grows as 1 / light

`term` gets the covariates `c` (`Covariates`) and the parameters by name, and returns, per pixel, what its
stage takes:

  illumination  a factor on the shot-noise variance: 1 / the light's relative change (projector on)
  image_noise   image-noise variance relative to the pattern's shot noise, added (read noise, ambient light)
  disparity     disparity variance in px^2, added (a noise floor); converted to range by (Z^2 / (f b))^2
  range         range variance in m^2, added
  variance      a factor on the total variance so far

The explanation is the docstring's first line. A built-in effect is the same kind of class, written against the
prediction itself (`Effect.apply`, `apply_tangent`) where its physics needs more than a term. Load the file with
`--effects FILE.py` (rig fit, compare, diagnose; the TUI's Results screen), or publish effects from an installed
package under the entry-point group `rig.effects`.
"""

from __future__ import annotations

import hashlib
import importlib.util
import keyword
import sys
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..parts.component import EFFECTS, Effect, EffectFileError, forget, registered_by
from ..data.model_data import ModelData
from ..parts.parameters import Param
from ..parts.prediction import EffectStage, Prediction
from ..parts.tangents import plus, scale

STAGES = {
    "illumination": EffectStage.ILLUMINATION,
    "image_noise": EffectStage.IMAGE_NOISE,
    "disparity": EffectStage.DISPARITY,
    "range": EffectStage.DISPARITY,
    "variance": EffectStage.EMPIRICAL,
}


@dataclass(eq=False)
class Covariates:
    """What a user effect may depend on, one value per pixel-stop.

    z_m: range (m; the true range, `ModelData.z0_m`, not the samples' mean, which sits a little beyond it); rho2, rho: squared and plain normalised radius from the principal point
    (tan of the off-axis angle); cos_off_axis = 1 / sqrt(1 + rho2); x_norm, y_norm: (u - cx) / fx,
    (v - cy) / fy; u_px, v_px: pixel column and row; cos_incidence, incidence_deg: the angle at
    which the ray meets the wall (plane fitted per stop); brightness_dn: mean IR brightness
    (DN, NaN without IR images or where the IR saturated); ambient_ratio: ambient / pattern light (NaN
    without projector-off frames, or saturated); stop: the stop's index; time_s: the stop's middle, s after the first began;
    projector_on; fb_px_m: focal length x baseline (px m); depth_unit_m. Per-pixel statistics
    pool a stop's frames, so time within a stop enters only through the per-frame series.
    """

    data: ModelData

    @property
    def z_m(self) -> np.ndarray:
        return self.data.z0_m

    @property
    def rho2(self) -> np.ndarray:
        return self.data.rho2

    @cached_property
    def rho(self) -> np.ndarray:
        return np.sqrt(self.data.rho2)

    @cached_property
    def cos_off_axis(self) -> np.ndarray:
        return 1.0 / np.sqrt(1.0 + self.data.rho2)

    @property
    def x_norm(self) -> np.ndarray:
        return self.data.x_norm

    @property
    def y_norm(self) -> np.ndarray:
        return self.data.y_norm

    @property
    def u_px(self) -> np.ndarray:
        return self.data.u_px

    @property
    def v_px(self) -> np.ndarray:
        return self.data.v_px

    @property
    def cos_incidence(self) -> np.ndarray:
        return self.data.cos_inc

    @cached_property
    def incidence_deg(self) -> np.ndarray:
        return np.degrees(np.arccos(np.clip(self.data.cos_inc, -1.0, 1.0)))

    @property
    def brightness_dn(self) -> np.ndarray:
        return self.data.ir

    @property
    def ambient_ratio(self) -> np.ndarray:
        return self.data.ambient_ratio

    @property
    def stop(self) -> np.ndarray:
        return self.data.stop

    @cached_property
    def time_s(self) -> np.ndarray:
        t = self.data.stops
        return np.full(len(self.data), np.nan) if t is None else t.time_s[self.data.stop]

    @property
    def projector_on(self) -> np.ndarray:
        return self.data.projector_on

    @property
    def fb_px_m(self) -> float:
        return self.data.fb_px_m

    @property
    def depth_unit_m(self) -> float:
        return self.data.depth_unit_m


class TermEffect(Effect):
    """An effect written as a per-pixel term of the covariates (see the module docstring): a subclass sets `name`,
    `stage` (one of STAGES, by name), `params`, `signature` and a docstring, and writes `term(self, c, **params)`."""

    #: the stage by name, as the subclass gave it (`stage` becomes the prediction's stage it joins at)
    stage_name: ClassVar[str] = ""
    #: the file it was loaded from, for messages
    source: str = ""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        given = cls.__dict__.get("stage")
        if isinstance(given, str):
            cls.stage_name = given
            cls.stage = STAGES.get(given)  # type: ignore[assignment]
        if "explanation" not in cls.__dict__:
            doc = (cls.__doc__ or "").strip().splitlines()
            cls.explanation = doc[0].rstrip(".") if doc else f"{cls.name} (written by the user)"

    def __init__(self) -> None:
        _check_definition(self)

    def term(self, c: Covariates, **params: float) -> np.ndarray:
        """The per-pixel value its stage takes (the module docstring), from the covariates and the parameters."""
        raise NotImplementedError

    def evaluate(self, d: ModelData, p: Any) -> np.ndarray:
        """The function's per-pixel output for parameter values `p` (its own, `own`, or a model's by qualified name);
        an exception from the function is an EffectFileError naming the effect, its file and the values."""
        values = self.own(p)._asdict()
        try:
            out = np.asarray(self.term(covariates(d), **values), dtype=float)
        except EffectFileError:
            raise
        except Exception as e:
            at = ", ".join(f"{k}={v:.4g}" for k, v in values.items())
            ranges = ", ".join(f"{q.name} in [{q.min:g}, {q.max:g}]" for q in self.params)
            raise EffectFileError(f"effect {self.name}{_where(self)}: term({at}) failed ({type(e).__name__}: {e}); the "
                                  f"fit may try any value in its range ({ranges}): make the function work over it, or "
                                  "narrow the range") from None
        return np.broadcast_to(out, d.z_m.shape)

    def start(self, d: ModelData, pred: Prediction) -> dict[str, float]:
        values = {q.name: q.value for q in self.params}
        try:
            out = self.evaluate(d, {f"{self.name}.{k}": v for k, v in values.items()})
        except Exception as e:
            raise EffectFileError(f"effect {self.name}{_where(self)}: calling it with its start values failed "
                                  f"({type(e).__name__}: {e}); fix the function") from None
        bad = ~np.isfinite(out) | (out < 0)
        if bad.any():
            raise EffectFileError(f"effect {self.name}{_where(self)}: it returns {'non-finite' if (~np.isfinite(out)).any() else 'negative'} "
                                  f"values at its start values ({int(bad.sum())} of {out.size} pixels); a {self.stage_name} "
                                  "term must be finite and not negative")
        return values

    def apply(self, pred, p, d):
        out = self.evaluate(d, p)
        if self.stage_name == "illumination":
            pred.illum = pred.illum * np.where(d.projector_on, out, 1.0)
        elif self.stage_name == "image_noise":
            pred.image_terms = pred.image_terms + out
        elif self.stage_name == "disparity":
            pred.add(d.disparity_to_range(out))
        elif self.stage_name == "range":
            pred.add(out)
        else:
            pred.var_m2 = pred.var_m2 * out

    def apply_tangent(self, pred, p, d, t):
        """`apply` with the derivatives carried through: the function's own derivative with respect to each of its
        parameters by central differences of the function alone (one-sided at a bound), not of the likelihood."""
        own = self.own(p)
        out = self.evaluate(d, own)
        dout = t.seeded([(i, self._derivative(d, own, name)) for i, name in t.own_rows(self)])
        if self.stage_name == "illumination":
            factor = np.where(d.projector_on, out, 1.0)
            t.illum = plus(scale(t.illum, factor), scale(dout, np.where(d.projector_on, pred.illum, 0.0)))
            pred.illum = pred.illum * factor
        elif self.stage_name == "image_noise":
            t.image = plus(t.image, dout)
            pred.image_terms = pred.image_terms + out
        elif self.stage_name == "disparity":
            t.var = plus(t.var, scale(dout, d.disparity_to_range(1.0)))
            pred.add(d.disparity_to_range(out))
        elif self.stage_name == "range":
            t.var = plus(t.var, dout)
            pred.add(out)
        else:
            t.var = plus(scale(t.var, out), scale(dout, pred.var_m2))
            pred.var_m2 = pred.var_m2 * out

    def _derivative(self, d: ModelData, own: Any, name: str) -> np.ndarray:
        q = next(q for q in self.params if q.name == name)
        x = getattr(own, name)
        h = 1e-6 * abs(x) if x != 0 else 1e-9 * (q.max - q.min if np.isfinite(q.max - q.min) else 1.0)
        up, down = min(x + h, q.max), max(x - h, q.min)
        if up <= down:
            return np.zeros(len(d))
        f_up = self.evaluate(d, own._replace(**{name: up}))
        f_down = self.evaluate(d, own._replace(**{name: down}))
        return (f_up - f_down) / (up - down)


_COVARIATES: dict[int, tuple[ModelData, Covariates]] = {}


def covariates(d: ModelData) -> Covariates:
    """The covariates of `d` (one object per data set, so derived arrays are computed once)."""
    hit = _COVARIATES.get(id(d))
    if hit is None or hit[0] is not d:
        if len(_COVARIATES) > 16:
            _COVARIATES.clear()
        hit = (d, Covariates(d))
        _COVARIATES[id(d)] = hit
    return hit[1]


def _where(e: TermEffect) -> str:
    return f" (in {e.source})" if e.source else ""


def _check_definition(e: TermEffect) -> None:
    if type(e).name == Effect.name or not isinstance(e.name, str):
        raise EffectFileError(f"effect {type(e).__name__}{_where(e)}: give it a name (name = \"...\", a Python identifier)")
    if e.stage_name not in STAGES:
        raise EffectFileError(f"effect {e.name}{_where(e)}: stage {e.stage_name or type(e).stage!r} is not one of "
                              f"{', '.join(STAGES)}")
    if type(e).term is TermEffect.term:
        raise EffectFileError(f"effect {e.name}{_where(e)}: write its term(self, c, ...) (docs/effects.md)")
    if not e.name.isidentifier() or keyword.iskeyword(e.name) or e.name.startswith("empirical"):
        raise EffectFileError(f"effect name {e.name!r}{_where(e)} must be a Python identifier (and not 'empirical...')")
    seen = set()
    for q in e.params:
        if not isinstance(q, Param):
            raise EffectFileError(f"effect {e.name}{_where(e)}: params must be Param(name, start, min, max, unit, doc)")
        if not q.name.isidentifier() or q.name in seen:
            raise EffectFileError(f"effect {e.name}{_where(e)}: parameter name {q.name!r} is not a unique identifier")
        if not (q.min <= q.value <= q.max):
            raise EffectFileError(f"effect {e.name}{_where(e)}: parameter {q.name} starts at {q.value}, outside "
                                  f"its bounds {q.min}..{q.max}")
        seen.add(q.name)
    if not e.signature:
        raise EffectFileError(f"effect {e.name}{_where(e)}: give a signature, the residual pattern it explains in plain words")


def load_effects(path: str | Path) -> list[Effect]:
    """The effects a Python file defines: the classes it registers (@register), in order, then any other
    module-level `Effect` objects. Running the file again replaces what it registered."""
    path = Path(path)
    if not path.is_file():
        raise EffectFileError(f"{path} does not exist; pass a Python file that defines effects, classes registered "
                              "with @register (see docs/effects.md)")
    module_name = "rig_user_effects_" + hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise EffectFileError(f"{path} is not a Python file; name it *.py")
    module = importlib.util.module_from_spec(spec)
    forget(module_name)
    sys.modules[module_name] = module  # as an import does: dataclasses and pickling look the module up there
    try:
        spec.loader.exec_module(module)
    except BaseException as e:
        sys.modules.pop(module_name, None)  # as a failed import leaves nothing
        forget(module_name)
        if isinstance(e, SyntaxError):
            raise EffectFileError(f"{path}:{e.lineno}: syntax error ({e.msg}); fix the line") from None
        if isinstance(e, EffectFileError):
            raise EffectFileError(f"{e} (in {path})") from None
        if isinstance(e, Exception):
            raise EffectFileError(f"{path}: running it failed ({type(e).__name__}: {e}); fix the file") from None
        raise
    found = registered_by(module_name)
    theirs = [*found, *EFFECTS.values()]  # a built-in effect the file imports is not the file's
    found += [v for v in vars(module).values() if isinstance(v, Effect) and not any(v is e for e in theirs)]
    if not found:
        raise EffectFileError(f"{path} defines no effect; write a class of TermEffect registered with @register "
                              "(see docs/effects.md)")
    for e in found:
        if isinstance(e, TermEffect) and not e.source:
            e.source = str(path)
    return found
