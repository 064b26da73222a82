"""The Devices screen's live preview (issue 51) of the Experiment form's region of interest: the rows are the
region's (the plane against the simulated wall's geometry), the IR row is there, the images mark the region, and a
region beyond the camera's image is refused in the words a run's camera refuses it with (`RegionCamera.open`).
The real app, driven by Textual's pilot, on a 64x36 px simulated camera."""

from __future__ import annotations

import re

import pytest

pytest.importorskip("textual", reason="rig tui needs textual (pip install -e .[test])")

from drivers.errors import CameraError  # noqa: E402
from protocols.region_of_interest import Region, RegionCamera  # noqa: E402
from rig.devices import open_devices  # noqa: E402
from rig.tui.app import RigApp  # noqa: E402
from rig.tui.image_widgets import DIM, MARK  # noqa: E402
from tui_pilot import run, type_into, until  # noqa: E402

CAMERA = "fake:width=64,height=36,seed=3"
WIDTH, HEIGHT = 64, 36


def the_runs_refusal(region: Region) -> str:
    """What a run says of `region` on this camera: its RegionCamera refuses to open."""
    camera = RegionCamera(open_devices(CAMERA, "none:").camera, region)
    with pytest.raises(CameraError) as refused:
        camera.open()
    return str(refused.value)


def marked_cells(text) -> tuple[set[tuple[int, int]], list[tuple[int, int, int]], tuple[int, int]]:
    """From a CellImage's Rich text: the (row, column) half-cells drawn in MARK, the colours of all half-cells, and
    the grid's (rows, columns)."""
    lines = text.plain.split("\n")
    grid = [line for line in lines if line and set(line) == {"▀"}]
    marks, colours, offset = set(), [], 0
    style_at = {}
    for span in text.spans:
        for i in range(span.start, span.end):
            style_at[i] = span.style
    for r, line in enumerate(grid):
        for c in range(len(line)):
            style = style_at[offset + c]
            for half, colour in ((0, style.color), (1, style.bgcolor)):
                rgb = colour.get_truecolor()
                colours.append(tuple(rgb))
                if tuple(rgb) == MARK:
                    marks.add((2 * r + half, c))
        offset += len(line) + 1
    return marks, colours, (2 * len(grid), len(grid[0]))


@pytest.mark.slow  # ~6 s of wall time (the pilot types), ~2 s of CPU
def test_the_preview_shows_the_forms_region_its_plane_and_ir_and_refuses_one_beyond_the_image():
    async def go():
        app = RigApp(CAMERA, "none:", connect=False)
        async with app.run_test(size=(120, 40)) as pilot:
            app.devices.session.connect(CAMERA, "none:", tilt_deg=30.0, distance_m=1.0)  # a tilted simulated wall
            status, preview = app.devices.status, app.query_one("#preview-info")

            # a region reaching beyond the 64x36 image: one line, the run's own words, and no preview
            await pilot.press("f2")
            await type_into(pilot, "region-px", "50, 30, 20, 8")
            await pilot.press("f1", "v")
            await until(pilot, lambda: not app.devices.previewing and status.text != "live preview: v stops it",
                        "the refusal")
            assert status.text == the_runs_refusal(Region(50, 30, 20, 8)) and "\n" not in status.text, status.text

            # an off-centre region (the top right): the numbers are the region's
            await pilot.press("f2")
            await type_into(pilot, "region-px", "40, 2, 20, 12")
            await pilot.press("f1", "v")
            await until(pilot, lambda: "fill" in preview.plain, "the live preview")
            rows = preview.plain
            depth, ir = app.query_one("#depth-image"), app.query_one("#ir-image")
            texts = depth.plain, ir.plain, depth.content, ir.content
            await pilot.press("v")
            return rows, texts

    rows, (depth_legend, ir_legend, depth_text, ir_text) = run(go())
    assert "region: 20x12 px at column 40, row 2\n" in rows, rows
    # fakes/physics.wall_range_m: Z = D / (1 + tan(t) x), on the axis at D = 1 m, tilted by 30 deg, from the region's
    # pixels at their rays in the whole image; 4 standard errors, and the last digits shown (0.05 mm, 0.005 deg)
    d, d_se = (float(g) for g in re.search(r"wall: ([\d.]+) m \+/- ([\d.]+) mm on the axis, fill 100\.0 %", rows).groups())
    assert abs(d - 1.0) <= 4 * max(d_se, 0.005) / 1000 + 0.00005, rows
    t, t_se = (float(g) for g in re.search(r"tilt: ([-+][\d.]+) \+/- ([\d.]+) deg left-right", rows).groups())
    assert abs(t - 30.0) <= 4 * max(t_se, 0.005), rows
    mean_dn, share = (float(g) for g in re.search(r"IR: mean (\d+) DN, ([\d.]+) % saturated \(at 1023 DN\)",
                                                   rows).groups())
    assert 0 < mean_dn < 1023 and 0 <= share <= 100, rows
    assert re.fullmatch(r"bright 0\.\d{3} to dark 0\.\d{3} m, black: none", depth_legend), depth_legend
    assert re.fullmatch(r"IR: black \d+ to white \d+ DN", ir_legend), ir_legend
    # both images whole, the region's edge drawn: its box within a cell of the region's pixels, scaled to the cells;
    # the half-cells outside the box dimmed
    for text in (depth_text, ir_text):
        marks, colours, (rows_n, cols_n) = marked_cells(text)
        top, left = (min(m[k] for m in marks) for k in (0, 1))
        bottom, right = (max(m[k] for m in marks) for k in (0, 1))
        sy, sx = rows_n / HEIGHT, cols_n / WIDTH  # cells per pixel
        assert abs(top - 2 * sy) <= 1 and abs(bottom + 1 - 14 * sy) <= 1, (top, bottom, rows_n)
        assert abs(left - 40 * sx) <= 1 and abs(right + 1 - 60 * sx) <= 1, (left, right, cols_n)
        outside = (rows_n * cols_n) - (bottom - top + 1) * (right - left + 1)
        assert sum(max(rgb) <= round(DIM * 255) for rgb in colours) >= outside > 0
