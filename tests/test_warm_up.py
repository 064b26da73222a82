"""Warm-up: the plan's values (checked, and free to change on resume), and the drift's rule (protocols/warm_up.py),
checked against simulated series of known slope: its 95 % interval covers the true slope 95 % of the time, with
white and with autocorrelated noise (where least squares' own s.e. would not)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import linregress, t as t_dist

from cli_in_process import rig_in_process
from protocols import perpendicular
from protocols.plan_check import resume_problems
from protocols.warm_up import drift_estimate

# --- the rule ----------------------------------------------------------------------------------


@pytest.mark.parametrize("rho", [0.0, 0.6])
def test_the_drifts_95_percent_interval_covers_the_true_slope_95_percent_of_the_time(rho):
    """400 windows of 300 frames (10 s at 30 fps), true drift 1.2 mm/min, AR(1) noise of lag-1 correlation rho
    (fixed seed). The binomial s.e. of a 95 % coverage over 400 windows is 1.1 %: within 3 s.e. of 95 %."""
    rng = np.random.default_rng(20240551)
    n, reps, slope_mm_per_s = 300, 400, 0.02
    t_s = np.arange(n) / 30.0
    covered = ols_covered = 0
    for _ in range(reps):
        noise = lfilter([1.0], [1.0, -rho], rng.standard_normal(n)) * math.sqrt(1 - rho**2)  # unit variance
        depth_mm = slope_mm_per_s * t_s + 0.1 * noise
        est = drift_estimate(t_s, depth_mm)
        half = est.bound_mm_per_min - abs(est.drift_mm_per_min)  # t(0.975, n_e - 2) s.e.
        covered += abs(est.drift_mm_per_min - 60 * slope_mm_per_s) <= half
        ols = linregress(t_s, depth_mm)  # least squares' own s.e., which assumes independent residuals
        ols_covered += abs(ols.slope - slope_mm_per_s) <= t_dist.ppf(0.975, n - 2) * ols.stderr
    assert abs(covered / reps - 0.95) <= 3 * math.sqrt(0.95 * 0.05 / reps)
    if rho > 0:  # without the AR(1) correction the interval is half as wide as it should be: covers about 68 %
        assert ols_covered / reps < 0.80


def test_a_resumed_run_may_change_the_warm_up_and_only_that():
    before = perpendicular([1.0, 2.0]).params
    old_file = {k: v for k, v in before.items() if not k.startswith("warm_up_")}  # made before rig had a warm-up
    later = perpendicular([1.0, 2.0], warm_up_drift_mm_per_min=0.5, warm_up_max_s=3600.0)
    assert resume_problems("perpendicular", before, later, {"1.000m"}) == []
    assert resume_problems("perpendicular", old_file, later, {"1.000m"}) == []
    assert resume_problems("perpendicular", before, perpendicular([1.0, 2.0], gain=32), {"1.000m"}) == \
        ["plan gain 16.0 in the file, 32.0 now"]


@pytest.mark.parametrize("options,message", [
    (["--warm-up-drift-mm-per-min", "-1"], "warm_up_drift_mm_per_min = -1.0 is outside 0 to 100 mm/min (0: do not wait)"),
    (["--warm-up-drift-mm-per-min", "0.5", "--warm-up-max-s", "30"],
     "warm_up_max_s = 30 is shorter than warm_up_window_s = 60, so the drift is never judged; give warm_up_max_s "
     "of at least 60 s or a shorter window"),
])
def test_rig_run_refuses_a_warm_up_it_cannot_do_in_one_line(tmp_path, options, message):
    out = rig_in_process("run", "--protocol", "perpendicular", *options, "-o", tmp_path / "r.h5")
    assert out.returncode == 2
    assert message in out.stderr and out.stderr.count("\n") == 1
    assert not (tmp_path / "r.h5").exists()
