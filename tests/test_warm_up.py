"""Warm-up: a run waits until the frame mean depth stops drifting, and says how long it waited.

The plan's values are checked, and free to change on resume. The drift's rule (protocols/warm_up.py) is checked
against simulated series of known slope: its 95 % interval covers the true slope 95 % of the time, with white and
with autocorrelated noise (where least squares' own s.e. would not). The runner is checked on the fake camera's
`drift` effect (fakes/effects.py), whose clock is the simulated one: the wait it needs is computed here from the
effect's own formula, and the run must wait that long.
"""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import linregress, t as t_dist

from cli_in_process import rig_in_process
from fakes.camera import FakeCamera
from fakes.effects import Drift
from fakes.physics import NATIVE_WIDTH
from fakes.stage import FakeStage
from fakes.world import FakeWorld
from protocols import Runner, RunError, perpendicular
from protocols.plan_check import resume_problems
from protocols.recording import Recording
from protocols.warm_up import drift_estimate

WIDTH, HEIGHT = 16, 12
#: the runner judges the drift once per second of the camera's clock (warm_up.CHECK_S)
CHECK_S = 1.0


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


# --- the runner ----------------------------------------------------------------------------------


def _run(tmp_path, effects, *, threshold, window_s, max_s, name="w.h5", stops=(1.0,)):
    world = FakeWorld.perpendicular(1.0)
    camera = FakeCamera(world, width=WIDTH, height=HEIGHT, depth_scale_m=1e-4, effects=effects)
    events = []
    plan = perpendicular(stops_m=list(stops), frames_per_stop=3, warm_up_drift_mm_per_min=threshold,
                         warm_up_window_s=window_s, warm_up_max_s=max_s)
    Runner(camera, FakeStage(world), sleep=lambda s: None, progress=events.append).run(plan, tmp_path / name)
    with Recording(tmp_path / name) as rec:
        first = next(iter(rec.stops()))
    return first.attrs, events, camera


def _window_slope_mm_per_min(depth_m, t_end_s, window_s, fps):
    """The least-squares slope of a noiseless depth curve over the frames of the window ending at t_end_s."""
    t = np.arange(0.0, t_end_s + 0.5 / fps, 1.0 / fps)
    t = t[t >= t[-1] - window_s]
    return 60_000.0 * np.polyfit(t, depth_m(t), 1)[0]


def test_a_drifting_camera_waits_as_long_as_its_drift_says(tmp_path):
    """Drift: disparity d = d0 + a exp(-t / tau) (fakes/effects.py), so the depth Z = f b / d and the wall at 1 m
    drifts at Z^2 a / (f b tau) exp(-t / tau): 353 mm/min at first, below 10 mm/min after tau ln(35.3) = 14.3 s.
    The run judges the slope over its window, which trails that, with its 95 % margin: it goes on between the times
    the noiseless window slope falls to threshold + (3 - 1.96) s.e. and to threshold - (3 + 1.96) s.e. (the fitted
    slope 3 s.e. off either way), the latter plus one check."""
    drift, threshold, window_s = Drift(amplitude_px=0.5, tau_s=4.0), 10.0, 4.0
    attrs, events, camera = _run(tmp_path, [drift], threshold=threshold, window_s=window_s, max_s=120.0)
    scale = camera.intrinsics.width / NATIVE_WIDTH  # the effect's px are native; the image is rendered smaller
    fb_px_m = camera.intrinsics.fx * camera.baseline_m
    d0 = fb_px_m / 1.0

    def depth_m(t):
        return fb_px_m / (d0 + drift.amplitude_px * scale * np.exp(-t / drift.tau_s))

    rate0 = 60_000.0 * 1.0**2 * drift.amplitude_px * scale / (fb_px_m * drift.tau_s)
    t_formula = drift.tau_s * math.log(rate0 / threshold)
    assert rate0 == pytest.approx(353, rel=0.01) and t_formula == pytest.approx(14.25, abs=0.01)

    se = attrs["warm_up_drift_se_mm_per_min"]
    grid = np.arange(window_s, 30.0, 1.0 / camera.fps)
    slopes = np.array([_window_slope_mm_per_min(depth_m, t, window_s, camera.fps) for t in grid])
    earliest = grid[np.argmax(slopes <= threshold + (3 - 1.96) * se)]
    latest = grid[np.argmax(slopes <= threshold - (3 + 1.96) * se)] + CHECK_S
    waited = attrs["warm_up_s"]
    assert t_formula < earliest <= waited <= latest < t_formula + window_s + 2 * CHECK_S
    assert abs(attrs["warm_up_drift_mm_per_min"]) + 1.96 * se <= threshold
    texts = [e.text for e in events if e.kind in ("warm_up", "message")]
    assert any(t.startswith("warming up: 10 s of at most 120 s, drift +") for t in texts)
    assert f"warm after {waited:.0f} s: the depth drifts" in "\n".join(texts)
    assert all(e.summary["threshold_mm_per_min"] == threshold for e in events if e.kind == "warm_up")


def test_a_camera_without_drift_proceeds_after_one_window(tmp_path):
    attrs, events, _ = _run(tmp_path, [], threshold=10.0, window_s=3.0, max_s=60.0)
    assert 3.0 <= attrs["warm_up_s"] <= 3.0 + CHECK_S
    assert abs(attrs["warm_up_drift_mm_per_min"]) < 3 * attrs["warm_up_drift_se_mm_per_min"]  # no drift, within noise
    assert [e.kind for e in events].count("warm_up") == 2  # at 1 s and 2 s: the first window is not yet whole


def test_only_the_first_stop_after_the_warm_up_says_so(tmp_path):
    _run(tmp_path, [], threshold=10.0, window_s=2.0, max_s=60.0, stops=(1.0, 1.5))
    with h5py.File(tmp_path / "w.h5") as f:
        assert [("warm_up_s" in f["stops"][s].attrs) for s in ("1.000m", "1.500m")] == [True, False]


def test_a_camera_still_drifting_at_the_timeout_stops_the_run_with_one_line(tmp_path):
    with pytest.raises(RunError) as e:
        _run(tmp_path, [Drift(amplitude_px=0.5, tau_s=4.0)], threshold=10.0, window_s=4.0, max_s=8.0)
    message = str(e.value)
    assert "\n" not in message
    assert message.startswith("after 8 s of warm-up fake-camera's depth is not shown to drift under 10 mm/min (drift +")
    assert "--warm-up-max-s" in message and message.endswith("nothing was recorded")
    assert not (tmp_path / "w.h5").exists()


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


def test_rig_run_waits_when_asked_and_the_experiment_file_carries_it(tmp_path):
    toml = tmp_path / "e.toml"
    toml.write_text('[experiment]\nprotocol = "tilted"\ncamera = "fake:width=16,height=12"\noutput = "t.h5"\n'
                    "[parameters]\nframes_per_stop = 2\nwarm_up_drift_mm_per_min = 30\nwarm_up_window_s = 3\n")
    out = rig_in_process("run", toml, "--warm-up-max-s", "20")
    assert out.returncode == 0, out.stderr
    assert "warm after 3 s: the depth drifts" in out.stderr
    with Recording(tmp_path / "t.h5") as rec:
        assert (rec.protocol_params["warm_up_drift_mm_per_min"], rec.protocol_params["warm_up_max_s"]) == (30.0, 20.0)
        assert 3.0 <= rec.stop("tilted").attrs["warm_up_s"] <= 3.0 + CHECK_S


def test_the_wait_is_one_line_updated_on_a_terminal_and_a_line_a_minute_in_a_log():
    import io

    from protocols.runner import ProgressEvent
    from rig.reports.progress import TerminalProgress

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    waits = [ProgressEvent("warm_up", text=f"warming up: {s} s", summary={"waited_s": float(s)}) for s in range(1, 130)]
    done = ProgressEvent("message", text="warm after 130 s")
    log, terminal = io.StringIO(), Terminal()
    for stream in (log, terminal):
        progress = TerminalProgress(stream)
        for e in [*waits, done]:
            progress(e)
    assert log.getvalue().splitlines() == ["warming up: 1 s", "warming up: 60 s", "warming up: 120 s", "warm after 130 s"]
    assert terminal.getvalue().count("\n") == 1 and terminal.getvalue().endswith("\r\x1b[Kwarm after 130 s\n")
