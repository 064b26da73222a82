"""Per stop, the sums the consistency checks need (`rig.diagnosis.consistency`): measured and predicted fill rate,
and the frame mean's predicted variance, added chunk by chunk in one compiled pass."""

from __future__ import annotations

import numpy as np
from numba import njit

from ..models import ModelData, Prediction
from .bins import per_row


class StopSums:
    """Per stop: measured and predicted fill rate, and the frame mean's predicted variance, added chunk by chunk."""

    def __init__(self) -> None:
        self.rows: dict[int, np.ndarray] = {}  # stop -> sums (see `add`)

    def add(self, c: ModelData, pred: Prediction) -> None:
        """Chunk `c` and its prediction: per stop, in one compiled pass (`_stop_sums`), the sums of 1, fill f,
        f (1 - f) / frames, frames, predicted fill, Z, the independent part of the frame mean's variance
        (var - common Z^4) / Z^4 x gain, common, w common Z^4, w var (w = n - 1, about the pixel's consecutive pairs:
        lag-1 correlation, rig.models.data.independence) and the predicted fill's binomial term."""
        if len(c) == 0:
            return
        out = np.zeros((int(c.stop.max()) + 1, 11))
        _stop_sums(np.ascontiguousarray(c.stop), np.ascontiguousarray(c.fill, dtype=float),
                   np.ascontiguousarray(c.n, dtype=float), np.ascontiguousarray(c.z_m, dtype=float),
                   per_row(pred.var_m2), per_row(pred.common_inv2), per_row(pred.frame_mean_gain),
                   per_row(pred.fill), out)
        for key in np.flatnonzero(out[:, 0]).tolist():
            self.rows[key] = self.rows[key] + out[key] if key in self.rows else out[key].copy()


@njit(cache=True, nogil=True)
def _stop_sums(stop, fill, n, z_m, var_m2, common_inv2, gain, fill_p, out):  # pragma: no cover - compiled
    """`StopSums.add`'s sums of each row into its stop's row of `out`; var_m2, common_inv2, gain and fill_p hold one
    value for every row or one a row."""
    for i in range(stop.size):
        var = var_m2[i] if var_m2.size > 1 else var_m2[0]
        common = common_inv2[i] if common_inv2.size > 1 else common_inv2[0]
        g = gain[i] if gain.size > 1 else gain[0]
        fp = fill_p[i] if fill_p.size > 1 else fill_p[0]
        f = fill[i]
        frames = n[i] / max(f, 1e-12)
        w = max(n[i] - 1.0, 0.0)
        z2 = z_m[i] * z_m[i]
        z4 = z2 * z2  # Z^4, m^4
        s = stop[i]
        out[s, 0] += 1.0
        out[s, 1] += f
        out[s, 2] += f * (1.0 - f) / frames
        out[s, 3] += frames
        out[s, 4] += fp
        out[s, 5] += z_m[i]
        out[s, 6] += (var - common * z4) / z4 * g
        out[s, 7] += common
        out[s, 8] += w * common * z4
        out[s, 9] += w * var
        out[s, 10] += fp * (1.0 - fp) / frames
