"""The live preview's numbers (rig/tui/preview.py): one depth frame's fill rate and the wall's plane, against a plane
drawn here from the pinhole's geometry, and against the simulated camera looking at a tilted wall."""

from __future__ import annotations

import math

import numpy as np

from drivers.camera import Intrinsics
from rig.tui.devices_service import DeviceSession
from rig.tui.preview import shrink, wall_view

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
