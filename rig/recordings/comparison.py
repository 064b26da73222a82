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
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2, norm

from .camera_setup import BY_KEY, ITEMS, SetupDifference, setup_differences
from .recording_fits import RecordingResult
from .setup_effects import k_ratio, models_rounding, rounding

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
    "bias.scale": ("the depth scale differs: the camera's calibration (baseline, focal length) or its temperature",
                   "the depth scale changes from run to run: the camera's temperature (let it warm up) or a "
                   "recalibration between runs"),
    "bias.disparity_offset_px": ("the disparity offset differs: the camera's calibration (rectification) or the "
                                 "matcher's subpixel bias under other light",
                                 "the disparity offset changes from run to run: warm-up (let the camera warm up), "
                                 "or a calibration run between them"),
    "bias.offset_m": ("the wall's offset from the camera differs: the camera was mounted again, or the stage homed "
                      "elsewhere", "the mount or the stage's home moves between runs (check the mount; home the "
                      "stage before each run)"),
}


def p_text(p: float) -> str:
    """"p = 3.2e-05", or "p < 1e-300" where the normal's tail is below what a double holds."""
    return f"p = {p:.1e}" if p > 0 else "p < 1e-300"


def beyond_noise(r: RecordingResult) -> bool:
    """The model does not fit the recording within noise (its headline verdict): its Cramer-Rao errors, which assume
    the model is right, do not hold there. The one criterion of `rig compare` and `rig repeatability`."""
    return not r.error and r.verdict.startswith("beyond noise")


@dataclass
class Difference:
    """One parameter between two recordings."""

    parameter: str
    a: RecordingResult
    b: RecordingResult
    z: float  # (a - b) / its standard error
    p: float  # two-sided
    significant: bool | None  # None: not judged, the model does not fit one of the two within noise
    ratio: float = math.nan  # a / b as the set-up predicts it (k: the geometry, `setup_effects.k_ratio`); nan: none
    z_scaled: float = math.nan  # (a - ratio b) / its standard error: the difference the set-up does not explain
    scaled_differs: bool | None = None
    causes: list[str] = field(default_factory=list)  # the set-up items named as its cause (`camera_setup.ITEMS` keys)
    cause: str = ""  # the cause in words

    @property
    def value_a(self) -> float:
        return self.a.values[self.parameter]

    @property
    def value_b(self) -> float:
        return self.b.values[self.parameter]

    @property
    def differs(self) -> bool:
        """Differs beyond what the set-up explains: significant, or alike only where the set-up predicts a change."""
        return bool(self.significant) if self.scaled_differs is None else self.scaled_differs

    def sentence(self) -> str:
        p, where = self.parameter, f"{self.value_a:.5g} in {self.a.name} against {self.value_b:.5g} in {self.b.name}"
        if self.significant is None:
            return f"{p}: {where}; no verdict in standard errors (the model does not fit both within noise)"
        if not math.isfinite(self.z):
            return f"{p}: no standard error in one of the fits, so no test ({where})"
        if not self.significant and not self.differs:
            return f"{p} within noise ({abs(self.z):.1f} standard errors; {where})"
        if not self.significant:
            return f"{p} within noise ({abs(self.z):.1f} standard errors; {where}), {self.cause}"
        return f"{p} differs by {abs(self.z):.1f} standard errors ({p_text(self.p)}; {where}): {self.cause}"


@dataclass
class Pair:
    """Two recordings compared: what differs in their set-up, then their parameters (judged in standard errors only
    where the model fits both within noise)."""

    a: RecordingResult
    b: RecordingResult
    setup: list[SetupDifference]
    parameters: list[Difference]

    @property
    def names(self) -> list[str]:
        return [self.a.name, self.b.name]

    @property
    def misfit(self) -> list[RecordingResult]:
        """Of the two, those the model does not fit within noise (`beyond_noise`)."""
        return [r for r in (self.a, self.b) if beyond_noise(r)]

    @property
    def judged(self) -> bool:
        return not self.misfit

    def not_judged(self) -> str | None:
        """Why there is no verdict in standard errors (None: there is one)."""
        if not self.misfit:
            return None
        # the worst statistic, not the headline's size alone: a fill rate or a kurtosis can be what is beyond noise
        fits = " and ".join(f"{r.name} within noise ({r.verdict.removeprefix('beyond noise; ')}; headline error "
                            f"{r.headline_pct:.2f} % against {r.noise_pct:.2f} % of noise)" for r in self.misfit)
        text = (f"no verdict in standard errors: {self.misfit[0].model} does not fit {fits}, and standard errors hold "
                "only for a model that fits")
        rounding_cause = _rounding_cause(self)
        if rounding_cause:
            return f"{text}. The likely cause is {rounding_cause}"
        return f"{text}. Diagnose it (rig diagnose {self.misfit[0].name}) and compare with the model it finds (--model)"

    def setup_text(self) -> str:
        """The set-up first: what differs, or that it is the same in all both recordings hold."""
        if not self.setup:
            return f"the same set-up ({', '.join(recorded_labels([self.a.setup, self.b.setup])) or 'nothing recorded'})"
        text = "the set-up differs: " + "; ".join(d.sentence(self.names) for d in self.setup)
        depth_unit = any(d.item.key == "depth_unit_m" for d in self.setup)
        if depth_unit and models_rounding(self.a.model) and models_rounding(self.b.model):
            text += "; the model's quantization accounts for the depth unit"
        return text

    def verdict(self) -> str:
        """The pair in words: the set-up first, then what differs and why, or that they are alike within their errors,
        or why there is no verdict in standard errors."""
        head = f"{self.a.name} against {self.b.name}: {self.setup_text()}. "
        why_not = self.not_judged()
        if why_not:
            return head + why_not[0].upper() + why_not[1:]
        if not self.parameters:
            return head + "The two fits share no free parameter to compare"
        if not any(d.differs for d in self.parameters):
            alike = ("Alike once the set-up's geometry is taken out: " if any(d.significant for d in self.parameters)
                     else "Alike within their errors: ")
            return head + alike + "; ".join(d.sentence() for d in self.parameters)
        return head + "; ".join(d.sentence() for d in self.parameters if d.differs or d.significant)


def recorded_labels(setups: list[dict]) -> list[str]:
    """The set-up items every one of `setups` records, in words (the intrinsics and the resolution as one each)."""
    labels = {"fx_px": "intrinsics", "fy_px": "intrinsics", "cx_px": "intrinsics", "cy_px": "intrinsics",
              "width_px": "resolution", "height_px": "resolution"}
    out = [labels.get(i.key, i.label) for i in ITEMS if all(s.get(i.key) is not None for s in setups)]
    return list(dict.fromkeys(out))


def _rounding_cause(pair: Pair) -> str | None:
    """The depth unit, where it differs, the model leaves rounding out, and rounding shows in either recording."""
    if not any(d.item.key == "depth_unit_m" for d in pair.setup):
        return None
    if models_rounding(pair.a.model) or models_rounding(pair.b.model):
        return None
    shown = [x for x in ((rounding(r), r) for r in (pair.a, pair.b)) if x[0] is not None and x[0].visible]
    if not shown:
        return None
    q, r = max(shown, key=lambda x: x[0].share)
    return (f"the depth unit: rounding to {q.q_m * 1e3:.3g} mm adds q^2/12 = ({q.sigma_q_m * 1e3:.3g} mm)^2, "
            f"{100 * q.share:.0f} % of the variance measured at {q.z_m:.3g} m in {r.name}, which {r.model} does not "
            f"model: compare with --model {r.model}+quantization")


def _geometry(d: Difference, threshold: float) -> None:
    """k against the geometry: the ratio sigma_Z = Z^2 sigma_d / (f b) predicts (`setup_effects.k_ratio`), and whether
    it explains the difference (the rest within noise at the pair's `threshold`)."""
    ratio, moved = k_ratio(d.a.setup, d.b.setup)
    if d.parameter != "k" or not moved:
        return
    se = math.hypot(d.a.errors.get("k", math.nan), ratio * d.b.errors.get("k", math.nan))
    d.ratio = ratio
    d.z_scaled = (d.value_a - ratio * d.value_b) / se if se > 0 else math.nan
    if not math.isfinite(d.z_scaled):
        return
    d.scaled_differs = bool(2 * norm.sf(abs(d.z_scaled)) < threshold)
    names = " and ".join(BY_KEY[k].label for k in moved)
    verb = "explain" if len(moved) > 1 else "explains"
    law = (f"k scales as 1/(f b): k_a/k_b = {ratio:.4g} expected, {d.value_a / d.value_b:.4g} measured; "
           f"{abs(d.z_scaled):.1f} standard errors apart once taken out")
    if not d.scaled_differs:
        d.causes, d.cause = list(moved), f"the {names} {verb} it ({law})"
    elif d.significant:
        d.cause = f"more than the {names} {verb} ({law})"
    else:
        d.cause = f"but the {names} predict{'' if len(moved) > 1 else 's'} a difference ({law})"


def _attribute(d: Difference, pair: Pair) -> None:
    """The causes of a parameter's difference: the set-up's first (the geometry's exact scale, the depth unit's
    rounding, then whatever else differs that moves it), the parameter's general meaning only where none."""
    if d.significant is None or not d.differs:
        return
    if d.causes:  # the geometry explains it
        return
    causes, words = [], [d.cause] if d.cause else []
    if d.parameter in ("k", "lambda"):
        rounding_cause = _rounding_cause(pair)
        if rounding_cause:
            causes.append("depth_unit_m")
            words.append(f"the likely cause is {rounding_cause}")
    # the geometry and the depth unit are judged above; another serial is what a comparison of units tests
    skip = {"depth_unit_m", "baseline_m", "fx_px", "camera_serial"}
    other = [s.item for s in pair.setup if s.item.key not in skip and {d.parameter, "*"} & set(s.item.moves)]
    if other:
        causes += [i.key for i in other]
        verb = "changes" if len(other) == 1 else "change"
        words.append(f"the set-up differs in {', '.join(i.label for i in other)}, which {verb} {d.parameter}")
    if not causes:
        words.append(MEANING.get(d.parameter, (f"{d.parameter} differs",))[0])
    d.causes, d.cause = causes, "; ".join(words)


def differences(results: list[RecordingResult]) -> list[Pair]:
    """Each pair of fitted recordings: its set-up differences, and the differences of the free parameters both fits
    have (a verdict in standard errors only where the model fits both within noise; the bias against the stage's
    truth, `bias.*`, always)."""
    fitted = [r for r in results if not r.error]
    out = []
    for a, b in itertools.combinations(fitted, 2):
        pair = Pair(a, b, setup_differences([a.setup, b.setup]), [])
        shared = [n for n in a.free if n in b.free]
        threshold = ALPHA / max(1, len(shared))
        for n in shared:
            se = math.hypot(a.errors.get(n, math.nan), b.errors.get(n, math.nan))
            z = (a.values[n] - b.values[n]) / se if se > 0 else math.nan
            p = float(2 * norm.sf(abs(z))) if math.isfinite(z) else math.nan
            # the bias is fitted to the stops' mean depth with its own errors (rig.accuracy, the stops' scatter taken
            # in): judged whether or not the noise model fits
            judged = pair.judged or n.startswith("bias.")
            d = Difference(n, a, b, z, p, (math.isfinite(p) and p < threshold) if judged else None)
            if judged:
                _geometry(d, threshold)
                _attribute(d, pair)
            pair.parameters.append(d)
        out.append(pair)
    return out


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

    def sentence(self, cause: str = "") -> str:
        """In words; `cause`, where given, is what varies it (a set-up that differs between the runs) instead of what
        usually does."""
        where = (f"run-to-run {self.sd:.3g} against a reported error of {self.se:.3g}: ratio {self.ratio:.2f}, "
                 f"{100 * (1 - ALPHA):.0f} % interval {self.low:.2f}-{self.high:.2f} for {self.n} runs")
        if not math.isfinite(self.ratio):
            return f"{self.parameter}: no standard error to compare with ({where})"
        if self.honest:
            return f"{self.parameter}: the errors are honest ({where})"
        if self.ratio < 1:
            return (f"{self.parameter} varies less between runs than its errors say ({where}): the errors are "
                    "conservative (they were widened, e.g. for correlated frames)")
        usual = MEANING.get(self.parameter, ("", f"something that sets {self.parameter} changes from run to run"))[1]
        return (f"{self.parameter} varies between runs {self.ratio:.1f} times more than its errors allow ({where}): "
                f"{cause or usual}")


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
    """The runs in one sentence: first what differs in their set-up (then they are not repeats of one setting), then
    honest errors, or which parameter varies and what that suggests; and, when the model does not fit the runs within
    noise, that its errors do not hold for them (`misfit_caution`)."""
    fitted = [r for r in results or [] if not r.error]
    setup = setup_differences([r.setup for r in fitted])
    first = ""
    if setup:
        first = ("The runs are not of one set-up, so their scatter is not only the noise's: "
                 + "; ".join(d.sentence([r.name for r in fitted]) for d in setup) + ". ")
    bad = [s for s in scatters if math.isfinite(s.p) and not s.honest]
    if not bad:
        text = ("the errors are honest: every parameter's run-to-run scatter is what its reported errors allow ("
                + ", ".join(f"{s.parameter} {s.ratio:.2f}" for s in scatters) + ")")
    else:
        def cause(parameter: str) -> str:
            items = [d.item.label for d in setup
                     if d.item.key != "camera_serial" and {parameter, "*"} & set(d.item.moves)]
            verb = "changes" if len(items) == 1 else "change"
            return f"the set-up differs in {', '.join(items)}, which {verb} {parameter}" if items else ""

        text = "; ".join(s.sentence(cause(s.parameter)) for s in bad)
    caution = misfit_caution(results or [])
    return first + (f"{text}. {caution}" if caution else text)


def misfit_caution(results: list[RecordingResult]) -> str | None:
    """When the model is beyond noise on the runs: Cramer-Rao errors assume the model is right, and a misfit that
    moves with what differs between runs (where the stops fall on the depth grid, with a coarse depth unit) scatters
    the parameters beyond them. None when every run's fit is within noise."""
    beyond = [r for r in results if beyond_noise(r)]
    if not beyond:
        return None
    worst = max(beyond, key=lambda r: r.headline_pct)
    return (f"But {worst.model} does not fit {len(beyond)} of the {len([r for r in results if not r.error])} runs within "
            f"noise (headline error up to {worst.headline_pct:.2f} % against {worst.noise_pct:.2f} % of noise): its "
            "errors hold only for a model that fits, and the misfit can move from run to run (with a coarse depth unit, "
            f"where the stops fall on the depth grid); diagnose a run (rig diagnose {worst.name}) and repeat with the "
            "model it finds (--model)")
