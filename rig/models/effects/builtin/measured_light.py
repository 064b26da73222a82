"""`measured_light`: the shot noise follows the pattern light each pixel measured, not a geometric law of Z.

Simulated by the fake camera's `mottled_beam` (a diffuser that spreads the projector's light in soft patches,
fakes/effects.py), a pattern of light no geometric effect describes; the same effect stands for any other (a beam's
shape, an off-centre projector, lens vignetting), which the outside scenes (fakes/outside) render from physics
rig's effects do not share.
The diagnosis does not try it on its own (`diagnosed = False`): it explains any pattern of light, so it would take
the place of the law to be found (a beam's cos^n fall-off, the slant range), which predicts the light where no IR
image is at hand. A user adds it when the diagnosis says the residual follows position or brightness and no law
fits: `rig diagnose rec.h5 --model active+measured_light`."""

from __future__ import annotations

import numpy as np

from ..projector import need_projector
from ...data.model_data import ModelData
from ...data.pattern_light import LIGHT_WINDOWS_PX, choose_window, light_rows
from ...parts.component import Effect, register
from ...parts.parameters import Param
from ...parts.prediction import EffectStage
from ...parts.tangents import plus, scale


@register
class MeasuredLight(Effect):
    """The shot noise follows the pattern light P each pixel measured, not the base's 1/Z^2 law.

    Disparity variance from photon noise goes as 1/P (paper, eq. 7: sigma_d^2 ~ 1/I), and sigma_Z = Z^2 sigma_d /
    (f b), so the shot variance is k^2 Z^(2 lambda) x (P_ref / (Z^2 P))^gamma: the base's Z^(2 lambda) assumes P ~ 1/Z^2, and
    this factor replaces that law by the light each pixel saw, which holds the beam's shape, the wall's albedo and
    incidence, vignetting and the slant range together. gamma (`exponent`, fitted) is 1 for shot noise alone and
    tends to 2 where the imagers' read noise r counts (sigma_d^2 ~ (P + r^2) / P^2, Matthies' eq. as the paper's
    eq. 7); above 1 it also restores contrast the smoothing took from the light. P (DN) is the IR mean less the
    projector-off mean, smoothed with a Gaussian of sigma `window_px`, chosen from the data (`rig.models.data.pattern_light`; clipped IR taken
    from the nearest stop as P (Z'/Z)^2). P_ref (`pattern_ref_dn_m2`, DN m^2) is the data's median of Z^2 P, so the
    factor is 1 on a typical pixel and k keeps its meaning. Neither is fitted. Rows without a measured P (no IR
    image, clipped at every stop, the projector off) keep the base's law.
    """

    name = "measured_light"
    stage = EffectStage.ILLUMINATION
    needs = ()
    groupable = False  # the light can change from pixel to pixel (a window under 1 px): no grouped nodes
    diagnosed = False
    params = (Param("pattern_ref_dn_m2", 1.0, 0.0, np.inf, "DN m^2",
                    "the pattern light times Z^2 at which the factor is 1 (the data's median; not fitted)", vary=False),
              Param("window_px", LIGHT_WINDOWS_PX[-1], 0.0, np.inf, "px",
                    "the Gaussian sigma the measured light is averaged over (chosen from the data; not fitted)",
                    vary=False),
              Param("exponent", 1.0, 0.3, 3.0, "1",
                    "gamma in (P_ref / (Z^2 P))^gamma: 1 where shot noise dominates, toward 2 where read noise does"))
    signature = "the error follows the measured pattern light: larger where the IR image is darker at the same range"
    explanation = ("the projected light each pixel measured sets its shot noise (a beam's shape, vignetting, the wall's "
                   "albedo), not a geometric law of Z")

    twin = None  # the fake camera's mottled_beam makes what it describes; the diagnosis is not asked to name it
    position = 10

    def applicable(self, d):
        if d.sources is None or not any(s.light_raw is not None for s in d.sources):
            return "measured_light needs the IR image at stops with the projector on (record it: ir=True)"
        if not np.isfinite(light_rows(d, LIGHT_WINDOWS_PX[-1])).any():
            return "measured_light needs the IR image unclipped at some stop (lower the IR gain or exposure)"
        return need_projector(d, "measured_light")

    def start(self, d, pred):
        w = choose_window(d)
        p = light_rows(d, w)
        use = np.isfinite(p) & d.projector_on
        ref = float(np.median(d.z0_m[use] ** 2 * p[use])) if use.any() else 1.0
        return {"pattern_ref_dn_m2": ref, "window_px": w}

    def log_ratio(self, p, d: ModelData) -> np.ndarray:
        """ln(P_ref / (Z^2 P)) where P is measured and the projector on, else 0."""
        light = light_rows(d, float(p.window_px))
        use = np.isfinite(light) & d.projector_on
        return np.where(use, np.log(p.pattern_ref_dn_m2 / (d.z0_m**2 * np.where(use, light, 1.0))), 0.0)

    def apply(self, pred, p, d):
        pred.illum = pred.illum * np.exp(p.exponent * self.log_ratio(p, d))

    def apply_tangent(self, pred, p, d, t):
        g = self.log_ratio(p, d)
        f = np.exp(p.exponent * g)
        own = [(i, pred.illum * f * g)] if (i := t.row(self, "exponent")) is not None else []
        pred.illum = pred.illum * f
        t.illum = plus(scale(t.illum, f), t.seeded(own))
