"""The live preview's numbers (rig/tui/preview.py): one depth frame's fill rate and the wall's plane, against a plane
drawn here from the pinhole's geometry, and against the simulated camera looking at a tilted wall, from the whole
image or from a region of interest (the region's numbers are those of what a run records: RegionCamera's frame); the
IR image's level and saturation, counted as a run counts them."""

from __future__ import annotations

import math

import numpy as np

from drivers.camera import CameraSettings, Intrinsics
from protocols.region_of_interest import Region, RegionCamera
from protocols.stats import MeanImageAccumulator
from rig.tui.devices_service import DeviceSession
from rig.tui.preview import frame_view, ir_view, ir_words, shrink, view_rows, wall_view

D435 = Intrinsics(848, 480, 421.0, 421.0, 423.5, 239.5)


def test_a_tilted_plane_gives_its_tilt_distance_and_fill():
    # a wall through (0, 0, 2 m) / cos(t)... : its normal (sin t, 0, cos t) at 2 m from the camera, n . X = 2, so along
    # the ray X = Z (x, y, 1): Z = 2 / (cos t + x sin t), 1/Z linear in x, the tilt atan(b / a) = t
    t = math.radians(12.0)
    u, v = np.meshgrid(np.arange(D435.width), np.arange(D435.height))
    x = (u - D435.cx) / D435.fx
    z_m = 2.0 / (math.cos(t) + x * math.sin(t))
    unit_m = 1e-4
    depth = np.round(z_m / unit_m).astype(np.uint16)  # a depth unit's rounding: the only scatter
    depth[:48, :100] = 0  # a hole: no depth there
    view = wall_view(depth, D435, unit_m)
    assert view.fill_rate == 1 - 48 * 100 / depth.size  # exact: a count
    p = view.plane
    # the rounding scatters 1/Z by q / (sqrt(12) Z^2): the fit's standard errors come from it; 4 of them
    assert abs(p.tilt_deg - 12.0) <= 4 * p.tilt_se_deg and p.tilt_se_deg < 0.01
    assert abs(p.tilt_x_deg) <= 4 * p.tilt_x_se_deg
    assert abs(p.distance_m - 2.0 / math.cos(t)) <= 4 * p.distance_se_m


def test_the_simulated_camera_at_a_tilted_wall_shows_its_tilt():
    session = DeviceSession()
    session.connect("fake:width=64,seed=3", "none:", tilt_deg=20.0, distance_m=1.5)
    try:
        camera = session.devices.camera
        info = camera.info()
        frame = next(iter(camera.frames(1)))
    finally:
        session.disconnect()
    view = wall_view(frame.depth, info.intrinsics, info.depth_scale_m)
    p = view.plane
    # fakes/physics.wall_range_m: Z = D / (1 + tan(t) x), the plane's 1/Z = (1 + tan(t) x) / D; one frame's noise
    assert abs(p.tilt_deg - 20.0) <= 4 * p.tilt_se_deg and abs(p.distance_m - 1.5) <= 4 * p.distance_se_m
    assert view.fill_rate > 0.95


def test_the_image_shrinks_by_block_means_and_marks_blocks_without_depth():
    z = np.repeat(np.repeat(np.array([[1.0, 2.0, 3.0], [4.0, np.nan, 6.0]]), 4, axis=0), 5, axis=1)  # 8 x 15 px
    z[0, 0] = np.nan  # one pixel of a block without depth: the block's mean is of the others
    out = shrink(z, (2, 3))
    assert out.shape == (2, 3) and np.isnan(out[1, 1])
    assert np.array_equal(np.delete(out.ravel(), 4), [1.0, 2.0, 3.0, 4.0, 6.0])  # exact: means of equal numbers


# -- the region of interest and the IR image ------------------------------------------------------------------------
def tilted_frame(region: Region, tilt_deg: float = 30.0, distance_m: float = 1.0):
    """One frame (with IR) of the simulated camera at a tilted wall, the same camera's first frame through the run's
    RegionCamera (a twin: the same seed), and both cameras' info."""
    frames = []
    for through in (None, region):
        session = DeviceSession()
        session.connect("fake:width=64,height=36,seed=3,ir_gain=6", "none:", tilt_deg=tilt_deg, distance_m=distance_m)
        try:
            camera = RegionCamera(session.devices.camera, through) if through else session.devices.camera
            camera.configure(CameraSettings(projector_on=True, exposure_us=8500.0, gain=16.0))
            frames.append((next(iter(camera.frames(1, ir=True))), camera.info(), camera.ir_full_scale_dn))
        finally:
            session.disconnect()
    return frames


def test_an_off_centre_region_of_a_tilted_wall_gives_its_plane_and_the_runs_numbers():
    region = Region(40, 2, 20, 12)  # the top right: its centre ~20 px right of and ~10 px above the axis
    (frame, info, full_scale), (cropped, region_info, _) = tilted_frame(region)
    view = frame_view(frame, info, full_scale, region)
    p = view.plane
    # fakes/physics.wall_range_m: Z = D / (1 + tan(t) x): the plane on the axis at D, tilted by t, from the region only
    assert abs(p.distance_m - 1.0) <= 4 * p.distance_se_m and abs(p.tilt_deg - 30.0) <= 4 * p.tilt_se_deg
    assert abs(p.tilt_x_deg) <= 4 * p.tilt_x_se_deg
    # the region's pixels at the whole image's principal point (their rays wrong): the plane misses by far
    wrong = wall_view(region.crop(frame.depth), info.intrinsics, info.depth_scale_m).plane
    assert abs(wrong.distance_m - 1.0) > 10 * wrong.distance_se_m
    # what the run records of the region (RegionCamera: the cropped frame, the region's info), seen whole: the same
    # numbers, exactly (one implementation against itself: the same pixels in the same arithmetic)
    run = wall_view(cropped.depth, region_info.intrinsics, region_info.depth_scale_m)
    assert (view.fill_rate, p.distance_m, p.tilt_deg, p.tilt_x_deg) == (run.fill_rate, run.plane.distance_m,
                                                                         run.plane.tilt_deg, run.plane.tilt_x_deg)
    ir = MeanImageAccumulator(full_scale)
    ir.add(cropped.ir)
    assert view.ir.mean_dn == float(np.mean(cropped.ir, dtype=np.float64))
    assert view.ir.saturated == float(ir.saturated.mean()) and 0 < view.ir.saturated < 1  # ir_gain 6: some clip
    rows = dict(view_rows(view))
    assert rows["region"] == "20x12 px at column 40, row 2"
    assert rows["IR"] == f"mean {view.ir.mean_dn:.0f} DN, {100 * view.ir.saturated:.1f} % saturated (at 1023 DN)"
    # the images stay whole; each block's share of the region: 1 inside it, 0 outside
    assert view.image_m.shape == view.ir.image_dn.shape == view.inside.shape == (36, 64)
    assert np.array_equal(np.argwhere(view.inside == 1.0)[[0, -1]], [[2, 40], [13, 59]])
    assert view.inside.sum() == 20 * 12


def test_the_fill_and_the_ir_are_the_regions():
    depth = np.full((12, 16), 1000, np.uint16)
    depth[:, :8] = 0  # the left half has no depth
    ir = np.zeros((12, 16), np.uint8)
    ir[0, :] = 255  # the top row at the uint8 top: saturated (MeanImageAccumulator: the dtype's top when none given)
    region = Region(4, 0, 8, 8)  # half of it left, half right; its top row saturated
    intrinsics = Intrinsics(16, 12, 20.0, 20.0, 7.5, 5.5)
    view = wall_view(depth, intrinsics, 0.001, region=region)
    assert view.fill_rate == 0.5  # exact: 32 of 64 pixels
    seen = ir_view(ir, None, region=region)
    assert (seen.full_scale_dn, seen.saturated, seen.mean_dn) == (255, 1 / 8, 255 / 8)  # exact: counts
    assert ir_view(ir, 254).saturated == 16 / 192  # the camera's full scale when it has one; the whole image
    assert ir_view(ir.astype(np.float32), None).saturated is None  # a float image: not counted, as a run does not
    assert "saturation not known" in ir_words(ir_view(ir.astype(np.float32), None))
    assert dict(view_rows(view))["IR"] == "no IR image"  # (a camera that gives none)
