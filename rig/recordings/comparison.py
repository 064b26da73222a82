"""Fits of several recordings compared: do two cameras (or projector on and off, or two exposures) differ, and are
the reported errors honest over repeated runs?

Two recordings (`differences`): for each parameter both fits have, the difference in units of its standard error,
z = (a - b) / sqrt(se_a^2 + se_b^2) (independent recordings), and its two-sided p-value. A pair's parameters are
judged together: a difference counts where p is below ALPHA / (parameters compared) (Bonferroni), so three
parameters within noise do not make one false alarm in every thirtieth pair.

Repeated runs of one camera and setting (`scatter`): for each parameter, the run-to-run standard deviation s
against the root mean square of the Cramer-Rao errors; if the errors are honest, (n - 1) s^2 / se^2 follows
chi^2 with n - 1 degrees of freedom, which gives the test and the ratio's interval at the same level (1 - ALPHA):
the errors are honest where that interval holds 1.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2, norm

from .recording_fits import RecordingResult

#: the false-alarm rate of a verdict (per pair of recordings, or per parameter of a repeatability test)
ALPHA = 0.01
#: what a parameter's change means physically, when it differs between recordings or varies between runs
MEANING = {
    "k": ("the noise's scale differs (k is sigma at 1 m): another gain, exposure or unit",
          "something changes the noise's scale from run to run: the gain, the exposure, or warm-up (let the camera "
          "warm up and fix the gain)"),
    "lambda": ("the law itself changes (lambda is how the error grows with range): the projector, light that is not "
               "the projector's, or the geometry",
               "something changes how the error grows with range from run to run: light that is not the projector's "
               "(room light, daylight through a window), or the geometry (the mount, the wall)"),
}


def p_text(p: float) -> str:
    """"p = 3.2e-05", or "p < 1e-300" where the normal's tail is below what a double holds."""
    return f"p = {p:.1e}" if p > 0 else "p < 1e-300"


@dataclass
class Difference:
    """One parameter between two recordings."""

    parameter: str
    a: RecordingResult
    b: RecordingResult
    z: float  # (a - b) / its standard error
    p: float  # two-sided
    significant: bool

    @property
    def value_a(self) -> float:
        return self.a.values[self.parameter]

    @property
    def value_b(self) -> float:
        return self.b.values[self.parameter]

    def sentence(self) -> str:
        p, where = self.parameter, f"{self.value_a:.5g} in {self.a.name} against {self.value_b:.5g} in {self.b.name}"
        if not math.isfinite(self.z):
            return f"{p}: no standard error in one of the fits, so no test ({where})"
        if not self.significant:
            return f"{p} within noise ({abs(self.z):.1f} standard errors; {where})"
        why = MEANING.get(p, (f"{p} differs",))[0]
        return f"{p} differs by {abs(self.z):.1f} standard errors ({p_text(self.p)}; {where}): {why}"


def differences(results: list[RecordingResult]) -> list[list[Difference]]:
    """For each pair of fitted recordings, the differences of the free parameters both fits have."""
    fitted = [r for r in results if not r.error]
    out = []
    for a, b in itertools.combinations(fitted, 2):
        shared = [n for n in a.free if n in b.free]
        pair = []
        for n in shared:
            se = math.hypot(a.errors.get(n, math.nan), b.errors.get(n, math.nan))
            z = (a.values[n] - b.values[n]) / se if se > 0 else math.nan
            p = float(2 * norm.sf(abs(z))) if math.isfinite(z) else math.nan
            pair.append(Difference(n, a, b, z, p, math.isfinite(p) and p < ALPHA / max(1, len(shared))))
        out.append(pair)
    return out


def pair_verdict(pair: list[Difference]) -> str:
    """The pair in one sentence: what differs, or that they are alike within their errors."""
    if not pair:
        return "the two fits share no free parameter to compare"
    a, b = pair[0].a.name, pair[0].b.name
    differ = [d for d in pair if d.significant]
    if not differ:
        return f"{a} and {b} are alike within their errors: " + "; ".join(d.sentence() for d in pair)
    return f"{a} against {b}: " + "; ".join(d.sentence() for d in differ)


@dataclass
class Scatter:
    """One parameter over repeated runs: the run-to-run scatter against the errors rig reported."""

    parameter: str
    n: int
    mean: float
    sd: float  # run to run, ddof = 1
    se: float  # root mean square of the runs' Cramer-Rao errors
    ratio: float  # sd / se: 1 if the errors are honest
    low: float  # the ratio's interval at 1 - ALPHA, from chi^2 with n - 1 degrees of freedom
    high: float
    p: float  # two-sided: is the scatter what the errors say?

    @property
    def honest(self) -> bool:
        return self.p >= ALPHA

    def sentence(self) -> str:
        where = (f"run-to-run {self.sd:.3g} against a reported error of {self.se:.3g}: ratio {self.ratio:.2f}, "
                 f"{100 * (1 - ALPHA):.0f} % interval {self.low:.2f}-{self.high:.2f} for {self.n} runs")
        if not math.isfinite(self.ratio):
            return f"{self.parameter}: no standard error to compare with ({where})"
        if self.honest:
            return f"{self.parameter}: the errors are honest ({where})"
        if self.ratio < 1:
            return (f"{self.parameter} varies less between runs than its errors say ({where}): the errors are "
                    "conservative (they were widened, e.g. for correlated frames)")
        why = MEANING.get(self.parameter, ("", f"something that sets {self.parameter} changes from run to run"))[1]
        return f"{self.parameter} varies between runs {self.ratio:.1f} times more than its errors allow ({where}): {why}"


def scatter(results: list[RecordingResult]) -> list[Scatter]:
    """Each free parameter shared by every fitted run: its scatter against its reported errors."""
    fitted = [r for r in results if not r.error]
    if len(fitted) < 2:
        raise ValueError(f"repeatability needs two or more fitted runs, and {len(fitted)} fitted; record the run again "
                         "(rig run ... -o run2.h5) and give every run")
    names = [n for n in fitted[0].free if all(n in r.free for r in fitted)]
    out = []
    n = len(fitted)
    for name in names:
        v = np.array([r.values[name] for r in fitted])
        se = float(np.sqrt(np.mean([r.errors.get(name, math.nan) ** 2 for r in fitted])))
        sd = float(np.std(v, ddof=1))
        ratio = sd / se if se > 0 else math.nan
        stat = (n - 1) * ratio**2
        low = ratio * math.sqrt((n - 1) / chi2.ppf(1 - ALPHA / 2, n - 1)) if math.isfinite(ratio) else math.nan
        high = ratio * math.sqrt((n - 1) / chi2.ppf(ALPHA / 2, n - 1)) if math.isfinite(ratio) else math.nan
        p = float(2 * min(chi2.cdf(stat, n - 1), chi2.sf(stat, n - 1))) if math.isfinite(stat) else math.nan
        out.append(Scatter(name, n, float(v.mean()), sd, se, ratio, low, high, min(p, 1.0)))
    return out


def repeatability_verdict(scatters: list[Scatter], results: list[RecordingResult] | None = None) -> str:
    """The runs in one sentence: honest errors, or which parameter varies and what that suggests; and, when the model
    does not fit the runs within noise, that its errors do not hold for them (`misfit_caution`)."""
    bad = [s for s in scatters if math.isfinite(s.p) and not s.honest]
    if not bad:
        text = ("the errors are honest: every parameter's run-to-run scatter is what its reported errors allow ("
                + ", ".join(f"{s.parameter} {s.ratio:.2f}" for s in scatters) + ")")
    else:
        text = "; ".join(s.sentence() for s in bad)
    caution = misfit_caution(results or [])
    return f"{text}. {caution}" if caution else text


def misfit_caution(results: list[RecordingResult]) -> str | None:
    """When the model is beyond noise on the runs: Cramer-Rao errors assume the model is right, and a misfit that
    moves with what differs between runs (where the stops fall on the depth grid, with a coarse depth unit) scatters
    the parameters beyond them. None when every run's fit is within noise."""
    beyond = [r for r in results if not r.error and r.verdict.startswith("beyond noise")]
    if not beyond:
        return None
    worst = max(beyond, key=lambda r: r.headline_pct)
    return (f"But {worst.model} does not fit {len(beyond)} of the {len([r for r in results if not r.error])} runs within "
            f"noise (headline error up to {worst.headline_pct:.2f} % against {worst.noise_pct:.2f} % of noise): its "
            "errors hold only for a model that fits, and the misfit can move from run to run (with a coarse depth unit, "
            f"where the stops fall on the depth grid); diagnose a run (rig diagnose {worst.name}) and repeat with the "
            "model it finds (--model)")
