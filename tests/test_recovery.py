"""Parameter recovery through the whole chain: fake camera -> runner -> HDF5 -> fit.

The fake camera's physics implies sigma_Z = k Z^3 with the projector on and k Z^2 with it
off (fakes.physics.base_truth). A 32x18 image with 50 frames per stop gives ~320k samples
per run, so the fit's standard errors (~0.0023 in lambda) are larger than the fake's small
departures from the pure model (depth-unit rounding at 0.5 m with a 0.05 mm unit, and the
curvature of Z = f b / d at 3 m), which stay below half a standard error.
"""

import numpy as np
import pytest

from rig.analysis import fit_recording
from simrig import record_perpendicular

SEEDS = range(40)
FRAMES = 50


@pytest.mark.parametrize("projector_on", [True, False], ids=["active", "passive"])
def test_fake_camera_parameters_recovered_with_calibrated_standard_errors(tmp_path, projector_on):
    fits, truth = [], None
    for seed in SEEDS:
        path, truth, _ = record_perpendicular(tmp_path / f"run{seed}.h5", seed=seed, projector_on=projector_on,
                                             frames=FRAMES)
        fits.append(fit_recording(path).fit)
    k, lam = truth
    assert lam == (3.0 if projector_on else 2.0)
    for f in fits[:8]:
        assert abs(f.lam - lam) < 3 * f.se_lam, f.report()
        assert abs(f.k - k) < 3 * f.se_k, f.report()
    lams, ks = np.array([f.lam for f in fits]), np.array([f.k for f in fits])
    assert abs(lams.std(ddof=1) / np.mean([f.se_lam for f in fits]) - 1) < 0.3
    assert abs(ks.std(ddof=1) / np.mean([f.se_k for f in fits]) - 1) < 0.3
    # every pixel of every frame was used
    assert fits[0].n_samples == 11 * FRAMES * 32 * 18
