"""The projected pattern's light each pixel measured, for the `measured_light` effect.

P = I - A: the projector-on IR mean less the projector-off mean where the stop recorded one (DN), per pixel
(`covariates.raw_pattern_light`). Where the IR clipped, the mean is only a lower bound; there P is taken from the same
pixel at the nearest stop (in range) where it did not clip, scaled by the inverse square of the pixel's mean depth,
P = P' (Z' / Z)^2 (the projected light on the wall falls as 1/Z^2 along the ray; `fill_clipped_light`), and left
unknown (NaN) where no stop saw it unclipped.

The matcher averages the light over its window, and the raw image also holds the projected dots, so P is smoothed
with a Gaussian. How wide depends on the camera and on how its image was sampled (a D4xx's 7 px census window at
848x480; an image binned or cropped from the sensor sees a window of other size), so the window is chosen from the
data among LIGHT_WINDOWS_PX: the one whose light best explains how each pixel's variance differs from the others' at
the same stop (`choose_window`).
"""

from __future__ import annotations

import numpy as np

from .covariates import StopSource, rows_by_stop, _into, _nearest_pixel_rows
from .smoothing import smoothed

#: the Gaussian widths (sigma, px) the light may be averaged over; the largest is the brightness covariate's window
#: (`loading.BRIGHTNESS_WINDOW_PX`)
LIGHT_WINDOWS_PX = (0.7, 1.0, 1.5, 2.0, 3.0, 5.0, 7.0)
#: a smoothed value is known where at least this share of its weight comes from pixels whose light is known
KNOWN_SHARE = 0.5


def fill_clipped_light(sources: list[StopSource]) -> None:
    """Where a stop's IR clipped (light_raw NaN), P from the same pixel at the nearest stop in range that saw it,
    times (Z' / Z)^2 of the pixel's mean depths; in place. Pixels no stop saw unclipped stay NaN. The pixel's own
    value, not its neighbourhood's: the pixels that clip are the bright dots, and a local mean would take them for
    average ones (0.65 of the truth on the fake camera's 5:1 dots, against 0.96 pixel by pixel)."""
    have = [s for s in sources if s.light_raw is not None and s.mean_m is not None]
    medians = {id(s): float(np.nanmedian(np.where(s.mean_m > 0, s.mean_m, np.nan))) for s in have}
    for s in have:
        todo = np.isnan(s.light_raw) & (s.mean_m > 0)
        s.light_clipped = int(np.count_nonzero(todo))
        if not todo.any():
            continue
        out = s.light_raw.astype(np.float64)
        others = sorted((o for o in have if o is not s), key=lambda o: abs(np.log(medians[id(o)] / medians[id(s)])))
        with np.errstate(divide="ignore", invalid="ignore"):
            for o in others:  # nearest in range first: the least extrapolated
                ok = todo & np.isnan(out) & np.isfinite(o.light_raw) & (o.light_raw > 0) & (o.mean_m > 0)
                out[ok] = o.light_raw[ok] * (o.mean_m[ok] / s.mean_m[ok]) ** 2
        s.light_filled = int(np.count_nonzero(todo & np.isfinite(out)))
        s.light_raw = out.astype(np.float32)


def light_note(d) -> str | None:
    """What the measured light did with clipped IR, in words (None where none clipped)."""
    if d.sources is None:
        return None
    clipped = sum(s.light_clipped for s in d.sources)
    if not clipped:
        return None
    filled = sum(s.light_filled for s in d.sources)
    return (f"measured_light: the IR clipped at {clipped} pixel-stops; {filled} take the pattern light from the nearest "
            f"stop that saw it, as 1/Z^2, and {clipped - filled} keep the base's law (no stop saw them unclipped)")


def light_image(source: StopSource, window_px: float) -> np.ndarray | None:
    """The stop's pattern light smoothed over a Gaussian of sigma window_px (DN): a normalised convolution, so unknown
    pixels do not pull their neighbours down; NaN where less than KNOWN_SHARE of the weight is known or P <= 0."""
    if source.light_raw is None:
        return None
    got = source.light_smoothed.get(window_px)
    if got is None:
        got = source.light_smoothed[window_px] = _normalised(source.light_raw, window_px)
    return got


def _normalised(light: np.ndarray, window_px: float) -> np.ndarray:
    """`light` smoothed with the unknown (NaN) pixels left out of every average; NaN where less than KNOWN_SHARE of
    the weight is known or the average is not positive (float32)."""
    known = np.isfinite(light)
    total = smoothed(np.where(known, light, 0.0), window_px)
    weight = smoothed(known.astype(np.float64), window_px)
    with np.errstate(divide="ignore", invalid="ignore"):
        p = total / weight
    return np.where((weight >= KNOWN_SHARE) & (p > 0), p, np.nan).astype(np.float32)


def light_rows(d, window_px: float) -> np.ndarray:
    """P (DN) smoothed over window_px for the rows of `d` (the nearest pixel's); NaN where unknown or the stop has no
    pattern light (projector off, no IR). Cached on `d` by window."""
    def compute() -> np.ndarray:
        out = np.full(len(d), np.nan)
        if d.sources is not None:
            for s, rows in rows_by_stop(d):
                image = light_image(d.sources[s], window_px)
                if image is not None:
                    with _into(out, rows) as part:
                        _nearest_pixel_rows(image, np.ascontiguousarray(d.u_px[rows]),
                                            np.ascontiguousarray(d.v_px[rows]), part)
        return out

    return d.column(f"column:light@{window_px:g}", compute)


def choose_window(d) -> float:
    """The window (px, of LIGHT_WINDOWS_PX) whose light best explains the variance within each stop: the largest
    share of the spread of ln s^2 about its stop's mean explained by a common slope on ln P about its stop's mean
    (projector-on rows with P known at every window and s^2 > 0). The largest window when nothing tells them apart."""
    with np.errstate(divide="ignore", invalid="ignore"):
        lights = [light_rows(d, w) for w in LIGHT_WINDOWS_PX]
        use = (d.s2_m2 > 0) & np.all([np.isfinite(p) for p in lights], axis=0)
        if np.count_nonzero(use) < 10:
            return LIGHT_WINDOWS_PX[-1]
        stop = d.stop[use]
        count = np.bincount(stop).astype(float)
        seen = count > 0

        def centred(x: np.ndarray) -> np.ndarray:
            means = np.bincount(stop, weights=x) / np.where(seen, count, 1.0)
            return x - means[stop]

        y = centred(np.log(d.s2_m2[use]))
        best, best_gain = LIGHT_WINDOWS_PX[-1], 0.0
        for w, p in zip(LIGHT_WINDOWS_PX, lights):
            x = centred(np.log(p[use]))
            sxx, sxy = float(x @ x), float(x @ y)
            gain = sxy * sxy / sxx if sxx > 0 and sxy < 0 else 0.0  # more light, less noise: the only sign that counts
            if gain > best_gain * (1 + 1e-9):
                best, best_gain = w, gain
    return best
