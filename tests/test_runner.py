"""The runner end to end on the simulated rig: what it records, errors, resume, abort."""

import json

import h5py
import numpy as np
import pytest

from drivers.camera import CameraSettings, FrameMetadata
from fakes.camera import FakeCamera
from fakes.stage import FakeStage
from fakes.world import FakeWorld
from protocols import Runner, RunError, perpendicular, tilted
from protocols.runner import ProgressEvent, RunControl
from rig.devices import open_devices
from protocols.recording import Recording
from protocols.stop_journal import journal_dir
from protocols.stats import PixelMomentAccumulator
from simrig import record_perpendicular

STOPS = [0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0]


def test_perpendicular_records_every_stop_with_positions_settings_and_series(tmp_path):
    path, _, devices = record_perpendicular(tmp_path / "a.h5", frames=12, width=24, ambient_frames=3,
                                            effects="ambient(ambient_e_per_ms=20)")
    with Recording(path) as rec:
        assert rec.protocol == "perpendicular"
        assert rec.protocol_params["stops_m"] == STOPS
        assert rec.calibration.depth_scale_m == pytest.approx(5e-5)
        assert rec.calibration.fx == pytest.approx(425 * 24 / 848)
        assert rec.attrs["camera_model"].startswith("Fake D435")
        assert "ended_utc" in rec.attrs
        stops = list(rec.stops())
    assert [s.label for s in stops] == [f"{z:.3f}m" for z in STOPS]
    for s, z in zip(stops, STOPS):
        assert s.commanded_position_m == z
        assert abs(s.measured_position_m - z) < 0.002
        assert s.settings_read_back == {"projector_on": True, "exposure_us": 8500.0, "gain": 16.0, "auto_exposure": False}
        assert s.n_frames == 12 and s.stats.count.max() == 12
        assert np.nanmedian(s.stats.mean_m) == pytest.approx(z, rel=0.01)
        assert len(s.series.frame_number) == 12
        assert np.all(np.diff(s.series.frame_number) == 1)
        assert np.all(np.diff(s.series.timestamp_ms) > 0)
        assert np.nanmean(s.series.center_mean_m) == pytest.approx(z, rel=0.01)
        assert s.ir_mean is not None and s.ir_mean.shape == s.stats.count.shape
        assert s.ambient_ir_mean is not None
    # with the projector off the IR image shows the ambient light: 20 e-/ms * 8.5 ms * 0.04 DN/e-
    # = 6.8 DN at every distance; the projected pattern falls as 1/Z^2
    ambient = np.array([s.ambient_ir_mean.mean() for s in stops])
    assert ambient == pytest.approx(6.8, rel=0.05)
    pattern = {s.commanded_position_m: s.ir_mean.mean() - 6.8 for s in stops}
    assert pattern[1.0] / pattern[2.0] == pytest.approx(4.0, rel=0.05)


def test_night_time_active_run_sees_no_light_with_the_projector_off(tmp_path):
    path, _, _ = record_perpendicular(tmp_path / "n.h5", frames=4, width=16, ambient_frames=2, stops_m=[1.0])
    with Recording(path) as rec:
        (stop,) = list(rec.stops())
    assert stop.ambient_ir_mean.mean() < 0.5 and stop.ir_mean.mean() > 50  # 2270 e- * 0.04 DN/e- = 91 DN


@pytest.mark.numeric
def test_stored_statistics_equal_numpy_on_the_raw_frames(tmp_path):
    """The file's statistics (the runner's streaming accumulator) against numpy's two passes over the raw frames
    the file keeps: counts exactly, the moments within both implementations' rounding (tests/moment_bounds.py)."""
    from moment_bounds import accumulator_bounds, numpy_bounds, numpy_moments

    path, _, _ = record_perpendicular(tmp_path / "raw.h5", frames=25, width=40, keep_raw=True,
                                      effects="outliers(fraction=0.02)", stops_m=[0.5, 2.0, 3.0])
    with h5py.File(path) as f:
        scale = f["camera"].attrs["depth_scale_m"]
        for label in f["stops"]:
            g = f["stops"][label]
            raw = g["raw_depth"][()]
            want, ours, theirs = numpy_moments(raw, scale), accumulator_bounds(raw, scale), numpy_bounds(raw, scale)
            np.testing.assert_array_equal(g["count"][()], want["count"])
            for name in ("mean_m", "m2_m2", "m3_m3", "m4_m4"):
                got = g[name][()]
                both = np.isfinite(want[name])  # numpy's mean of no sample is NaN, as the file's
                assert np.array_equal(np.isfinite(got), both), (label, name)
                diff = np.abs(got[both] - want[name][both])
                assert np.all(diff <= (ours[name] + theirs[name])[both]), (label, name)


def test_interrupted_run_keeps_completed_stops_and_resumes(tmp_path):
    path = tmp_path / "r.h5"
    plan = perpendicular(frames_per_stop=10)
    cam = "fake:width=16,height=9,seed=3"
    # the camera "unplugs" during the 5th stop (frames 40..49)
    devices = open_devices(cam + ",fail_at_frame=45", "fake:")
    with pytest.raises(RunError) as err:
        Runner(devices.camera, devices.stage, sleep=devices.sleep).run(plan, path)
    msg = str(err.value)
    assert "disconnected at frame 45" in msg and "4 of 11 stops are saved" in msg and "--resume" in msg
    assert "\n" not in msg
    with Recording(path) as rec:
        assert rec.stop_labels() == ["0.500m", "0.750m", "1.000m", "1.250m"]
        assert "ended_utc" not in rec.attrs
    # the completed stops are files of their own beside the header until the run ends; the half-done one left nothing
    assert sorted(p.name for p in journal_dir(path).iterdir()) == ["0.500m.h5", "0.750m.h5", "1.000m.h5", "1.250m.h5"]

    with pytest.raises(RunError, match="already exists.*--resume"):
        Runner(devices.camera, devices.stage).run(plan, path)

    devices = open_devices(cam, "fake:")
    moves = []
    orig = devices.stage.move_to
    devices.stage.move_to = lambda z: moves.append(z) or orig(z)
    result = Runner(devices.camera, devices.stage, sleep=devices.sleep).run(plan, path, resume=True)
    assert result.skipped == ["0.500m", "0.750m", "1.000m", "1.250m"]
    assert result.recorded == [f"{z:.3f}m" for z in STOPS[4:]]
    assert moves == STOPS[4:]  # completed stops are not driven to again
    with Recording(path) as rec:
        assert rec.stop_labels() == [f"{z:.3f}m" for z in STOPS]
        assert "ended_utc" in rec.attrs and rec.assembled
    assert not journal_dir(path).exists()  # assembled: one HDF5 file, as docs/data-format.md describes
    with h5py.File(path) as f:
        assert sorted(f["stops"]) == sorted(f"{z:.3f}m" for z in STOPS)


def test_resume_refuses_a_different_experiment(tmp_path):
    path, _, _ = record_perpendicular(tmp_path / "a.h5", frames=3, width=8, stops_m=[1.0])
    devices = open_devices("fake:width=8", "fake:")
    with pytest.raises(RunError, match=r"holds a different experiment \(protocol 'perpendicular' in the file, 'tilted' now; .*\); resume it with the devices and plan that made it \(of the plan, only stops not yet recorded may change\), or write a new file$"):
        Runner(devices.camera, devices.stage).run(tilted(frames=3), path, resume=True)


def test_abort_from_another_thread_keeps_completed_stops(tmp_path):
    control = RunControl()

    def progress(e: ProgressEvent):
        if e.kind == "stop_done" and e.stop_index == 1:
            control.abort.set()

    devices = open_devices("fake:width=8", "fake:")
    result = Runner(devices.camera, devices.stage, progress=progress, sleep=devices.sleep, control=control).run(
        perpendicular(frames_per_stop=5), tmp_path / "x.h5")
    assert result.aborted and result.recorded == ["0.500m", "0.750m"]
    with Recording(tmp_path / "x.h5") as rec:
        assert rec.stop_labels() == ["0.500m", "0.750m"]


class MisreportingCamera(FakeCamera):
    """A fake camera whose frames report auto-exposure on: the run must refuse it."""

    def frames(self, n, *, ir=False):
        for f in super().frames(n, ir=ir):
            f.metadata = FrameMetadata(exposure_us=3300.0, gain=f.metadata.gain, projector_on=True, auto_exposure=True)
            yield f


def test_frames_whose_metadata_disagree_stop_the_run_before_recording(tmp_path):
    world = FakeWorld.perpendicular()
    cam = MisreportingCamera(world, width=8, height=5)
    with pytest.raises(RunError) as err:
        Runner(cam, FakeStage(world)).run(perpendicular(frames_per_stop=5), tmp_path / "m.h5")
    msg = str(err.value)
    assert "auto-exposure on (asked off)" in msg and "exposure 3300 us (asked 8500 us)" in msg
    assert "nothing was recorded" in msg and "\n" not in msg


def test_settings_out_of_range_give_one_line_error(tmp_path):
    devices = open_devices("fake:width=8", "fake:")
    # within what some camera takes (the plan's check), outside what this one does (the device's check)
    with pytest.raises(RunError, match=r"^fake-camera: exposure 180000 us is outside 1-165000 us; choose one inside.*nothing was recorded[^\n]*$"):
        Runner(devices.camera, devices.stage).run(perpendicular(exposure_us=180000), tmp_path / "e.h5")
    assert not (tmp_path / "e.h5").exists()  # nothing half-written to trip over on the next run


def test_stage_limits_refuse_before_moving(tmp_path):
    devices = open_devices("fake:width=8", "fake:")
    with pytest.raises(RunError, match=r"5.000 m is outside the travel of fake-stage, 0.300-3.500 m"):
        Runner(devices.camera, devices.stage, sleep=devices.sleep).run(
            perpendicular(stops_m=[1.0, 5.0], frames_per_stop=3), tmp_path / "l.h5")
    assert not (tmp_path / "l.h5").exists()  # refused before the first stop (tests/test_plan_check.py)


def test_tilted_wall_spans_half_to_two_metres(tmp_path):
    plan = tilted(frames=20)
    devices = open_devices("fake:width=106", "none:", tilt_deg=plan.params["tilt_deg"], distance_m=plan.params["distance_m"])
    Runner(devices.camera, devices.stage, sleep=devices.sleep).run(plan, tmp_path / "t.h5")
    with Recording(tmp_path / "t.h5") as rec:
        (stop,) = list(rec.stops())
    z = stop.stats.mean_m
    assert np.nanmin(z) == pytest.approx(0.5, abs=0.03)
    assert np.nanmax(z) == pytest.approx(2.0, abs=0.1)
    assert np.all(np.diff(np.nanmean(z, axis=0)) < 0)  # positive tilt: the right side is nearer
    assert stop.n_frames == 20


# -- dropped and duplicated frames ---------------------------------------------------------------

class _Transport(FakeCamera):
    """The fake camera behind a transport that loses, repeats or delays chosen frames, by frame number
    (exact instants, not random ones)."""

    def __init__(self, *a, lose=(), repeat=(), late_ms=None, **kw):
        super().__init__(*a, **kw)
        self.lose, self.repeat, self.late_ms = set(lose), set(repeat), dict(late_ms or {})
        self.delay_ms = 0.0

    def frames(self, n, *, ir=False):
        given, source = 0, super().frames(10 * n, ir=ir)
        while given < n:  # a frame is only made when it is wanted: no number is lost between calls
            f = next(source)
            if f.frame_number in self.lose:
                continue
            self.delay_ms += self.late_ms.get(f.frame_number, 0.0)
            if self.late_ms:  # a sensor stall: the numbers run on, the clock jumps
                f = type(f)(f.depth, f.frame_number, f.timestamp_ms + self.delay_ms, f.metadata, f.ir)
            for _ in range(2 if f.frame_number in self.repeat and given + 1 < n else 1):
                yield f
                given += 1


def _transport_run(tmp_path, **kw):
    world = FakeWorld.perpendicular(1.0)
    cam = _Transport(world, width=16, height=9, depth_scale_m=1e-4, **kw)
    Runner(cam, FakeStage(world), sleep=lambda s: None).run(perpendicular(stops_m=[1.0, 2.0], frames_per_stop=40), tmp_path / "t.h5")
    with Recording(tmp_path / "t.h5") as rec:
        return list(rec.stops())


def test_dropped_and_duplicated_frames_are_counted_per_stop_and_duplicates_left_out(tmp_path):
    # the first stop's frames are numbered 0..; lose 5, 9, 10, 11 (4 drops), repeat 20 and 30 (2 duplicates)
    first, second = _transport_run(tmp_path, lose={5, 9, 10, 11}, repeat={20, 30})
    assert first.attrs["frames_dropped"] == 4 and first.attrs["frames_duplicated"] == 2
    assert second.attrs["frames_dropped"] == 0 and second.attrs["frames_duplicated"] == 0
    # every stop has its 40 distinct frames: no frame folded in twice
    assert first.stats.count.max() == 40 and len(set(first.series.frame_number)) == 40
    assert not {5, 9, 10, 11} & set(first.series.frame_number.tolist())


def test_a_stall_with_consecutive_numbers_is_counted_from_the_timestamps(tmp_path):
    # frames 15 and 25 come 3 and 2 frame periods late (at 30 fps): 2 + 1 frames' time went by without frames
    period = 1000 / 30
    first, _ = _transport_run(tmp_path, late_ms={15: 2 * period, 25: 1 * period})
    assert first.attrs["frames_dropped"] == 3 and first.attrs["frames_duplicated"] == 0


def test_the_fake_camera_drops_and_repeats_frames_on_request(tmp_path):
    devices = open_devices("fake:width=16,height=9,drop=0.1,duplicate=0.05,seed=3", "fake:")
    Runner(devices.camera, devices.stage, sleep=devices.sleep).run(perpendicular(stops_m=[1.0, 1.5], frames_per_stop=60),
                                                                   tmp_path / "d.h5")
    with Recording(tmp_path / "d.h5") as rec:
        stops = list(rec.stops())
    dropped = sum(s.attrs["frames_dropped"] for s in stops)
    repeated = sum(s.attrs["frames_duplicated"] for s in stops)
    # 120 frames kept: about 12 lost (binomial, sd 3.5) and 6 repeated (sd 2.4)
    assert 2 <= dropped <= 25 and 1 <= repeated <= 15
    assert all(s.stats.count.max() == 60 for s in stops)


def test_a_fit_notes_the_frames_lost_on_the_way(tmp_path):
    _transport_run(tmp_path, lose={3}, repeat={7})
    with Recording(tmp_path / "t.h5") as rec:
        notes = rec.notes()
    assert any("1.000m 1 dropped, 1 duplicated" in n for n in notes), notes
