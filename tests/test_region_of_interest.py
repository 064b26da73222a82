"""A region of interest (issue 51): a run with `--region-px x,y,width,height` records only that part of the image, as a
camera whose image is the region (protocols.region_of_interest), and every reader of the recording sees the region.

Independent of the cropping code: the same seed's whole-image run, cropped here with numpy, is the region's
recording, statistic for statistic; and a tilted wall, placed by the fake camera with the whole image's intrinsics,
comes back at its planned distance and tilt from an off-centre region only if the region's principal point is right
(the test moves it back to the whole image's and sees the plane go wrong).
"""

from __future__ import annotations

import json

import h5py
import numpy as np

from cli_in_process import rig_in_process as rig
from protocols.recording import Recording

CAMERA = "fake:width=32,height=18,seed=3"
REGION = (4, 2, 16, 10)  # x, y, width, height


def test_a_region_records_exactly_those_pixels_of_the_whole_image(tmp_path):
    whole, part = tmp_path / "whole.h5", tmp_path / "part.h5"
    common = ["run", "--protocol", "perpendicular", "--stops", "0.5,1.5,2.5", "--frames", "5", "--camera", CAMERA, "-q"]
    assert rig(*common, "-o", whole).returncode == 0
    done = rig(*common, "--region-px", ",".join(map(str, REGION)), "-o", part)
    assert done.returncode == 0, done.stderr
    x, y, w, h = REGION
    with Recording(whole) as a, Recording(part) as b:
        assert a.stop_labels() == b.stop_labels() == ["0.500m", "1.500m", "2.500m"]
        for label in a.stop_labels():
            sa, sb = a.stop(label).stats, b.stop(label).stats
            for name in ("count", "mean_m", "m2_m2", "m4_m4"):  # one implementation against itself: exact
                np.testing.assert_array_equal(getattr(sb, name), getattr(sa, name)[y:y + h, x:x + w], err_msg=name)
        ca, cb = a.calibration, b.calibration
        assert (cb.width, cb.height) == (w, h) and (cb.cx, cb.cy) == (ca.cx - x, ca.cy - y) and cb.fx == ca.fx
    with h5py.File(part) as f:
        extra = json.loads(f.attrs["camera"])["extra"]
        assert extra["region_px"] == list(REGION) and extra["full_image_px"] == [32, 18]
        assert json.loads(f.attrs["protocol_params"])["region_px"] == list(REGION)
    fitted = rig("fit", part)
    assert fitted.returncode == 0 and "the region 16x10 px at column 4, row 2 of the camera's 32x18 image" in fitted.stdout
    # a resumed run may not change the region: its stops would be of another part of the image
    resumed = rig(*common, "--region-px", "0,0,16,10", "-o", part, "--resume")
    assert resumed.returncode == 2 and "region_px" in resumed.stderr, resumed.stderr


def test_an_off_centre_region_of_a_tilted_wall_gives_the_planned_plane(tmp_path):
    part = tmp_path / "tilted.h5"
    done = rig("run", "--protocol", "tilted", "--tilt-deg", "31", "--camera", "fake:width=64,height=36,seed=5",
               "--frames", "12", "--region-px", "2,4,24,28", "-o", part, "-q")
    assert done.returncode == 0, done.stderr

    def wall() -> dict:
        out = rig("accuracy", part, "--json")
        assert out.returncode == 0, out.stderr
        return json.loads(out.stdout)["accuracy"]["walls"][0]

    got = wall()
    assert abs(got["distance_m"] - 0.8) < 4 * got["distance_se_m"], got
    assert abs(got["tilt_deg"] - 31.0) < 4 * got["tilt_se_deg"], got
    with h5py.File(part, "r+") as f:  # the principal point of the whole image: each pixel's ray is then wrong
        f["camera"].attrs["cx"] = f["camera"].attrs["cx"] + 2
    wrong = wall()
    assert abs(wrong["distance_m"] - 0.8) > 10 * wrong["distance_se_m"], wrong


def test_a_region_that_is_not_one_is_one_line(tmp_path):
    out = tmp_path / "r.h5"
    base = ["run", "--protocol", "perpendicular", "--stops", "0.5", "--frames", "3", "--camera", CAMERA, "-o", out, "-q"]
    for region, words in (("20,2,16,10", "reaches beyond the camera's 32x18 image (to column 36"),
                          ("4,2,16", "must be 4 whole numbers in px, x, y, width, height"),
                          ("4,2,4,10", "width = 4.0 is outside 8 to 100000"),
                          ("4.5,2,16,10", "is not a whole number")):
        p = rig(*base, "--region-px", region)
        lines = p.stderr.strip().splitlines()
        assert p.returncode == 2 and len(lines) == 1 and words in lines[0], (region, p.stderr)
        assert not out.exists()
