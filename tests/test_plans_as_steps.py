"""Plans tested as what they would do: their list of steps, with no camera, stage or file (bluesky-style).

A plan is a name, its parameters and a generator of steps (protocols/plan.py); `list(plan.steps())` is the
whole experiment as data, so each built-in protocol is checked here step by step, and every protocol in the
catalogue (built-in, plugins', registered) is checked for the shape the runner relies on. The runner that
executes steps against devices is tested elsewhere (tests/test_runner.py); resuming is the runner skipping
the stops a recording already has, by label, so the plan's part in it is its labels and `resume_problems`.
"""

from __future__ import annotations

import pytest

from drivers.camera import CameraSettings
from protocols import perpendicular, tilted
from protocols.catalogue import BUILT_IN, protocol_names, protocol_spec
from protocols.plan import Capture, Configure, Home, Move, Settle, WarmUp
from protocols.plan_check import resume_problems

#: the camera settings of every default plan: projector on, 8500 us, gain x1 (16), auto exposure off
DEFAULT_CAMERA = CameraSettings(projector_on=True, exposure_us=8500.0, gain=16.0, auto_exposure=False)


def stop(z_m: float, label: str, frames: int = 300, settle_s: float = 1.0, **capture) -> list:
    """The three steps of one stop: move there, settle, capture."""
    return [Move(z_m), Settle(settle_s), Capture(label, frames, **{"ir": True, **capture})]


#: the paper's perpendicular experiment, written out: 0.5-3.0 m in 0.25 m steps, 300 frames at each
PERPENDICULAR_DEFAULT = [
    Home(),
    Configure(DEFAULT_CAMERA),
    *stop(0.5, "0.500m"), *stop(0.75, "0.750m"), *stop(1.0, "1.000m"), *stop(1.25, "1.250m"),
    *stop(1.5, "1.500m"), *stop(1.75, "1.750m"), *stop(2.0, "2.000m"), *stop(2.25, "2.250m"),
    *stop(2.5, "2.500m"), *stop(2.75, "2.750m"), *stop(3.0, "3.000m"),
]

#: the tilted experiment: one stop of 600 frames, the camera 0.8 m from the centre of a wall tilted 31 degrees
TILTED_DEFAULT = [Home(), Configure(DEFAULT_CAMERA), *stop(0.8, "tilted", frames=600)]

#: each built-in protocol's default plan, step by step
EXPECTED_DEFAULT = {"perpendicular": PERPENDICULAR_DEFAULT, "tilted": TILTED_DEFAULT}


def steps(plan) -> list:
    return list(plan.steps())


# --- perpendicular -------------------------------------------------------------------------------------


def test_the_default_perpendicular_plan_step_by_step():
    plan = perpendicular()
    assert plan.name == "perpendicular" and plan.stops_param == "stops_m"
    assert steps(plan) == PERPENDICULAR_DEFAULT
    assert plan.params == {
        "stops_m": [0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0], "frames_per_stop": 300,
        "projector_on": True, "exposure_us": 8500.0, "gain": 16.0, "settle_s": 1.0, "ir": True,
        "ambient_frames": 0, "keep_raw": False,
        "warm_up_drift_mm_per_min": 0.0, "warm_up_window_s": 60.0, "warm_up_max_s": 1800.0, "region_px": [],
    }


def test_projector_off_changes_only_the_configure_step():
    got = steps(perpendicular(projector_on=False))
    assert got[1] == Configure(CameraSettings(projector_on=False, exposure_us=8500.0, gain=16.0, auto_exposure=False))
    assert got[:1] + got[2:] == PERPENDICULAR_DEFAULT[:1] + PERPENDICULAR_DEFAULT[2:]


def test_projector_on_and_off_are_the_same_stops():
    on, off = steps(perpendicular(projector_on=True)), steps(perpendicular(projector_on=False))
    assert [s for s in on if not isinstance(s, Configure)] == [s for s in off if not isinstance(s, Configure)]
    assert [s.settings.projector_on for s in on + off if isinstance(s, Configure)] == [True, False]


def test_given_stops_are_visited_in_the_order_given_with_the_capture_settings():
    plan = perpendicular([1.0, 0.5, 2.125], frames_per_stop=20, exposure_us=3000, gain=32, settle_s=0.0, ir=False,
                         ambient_frames=5, keep_raw=True)
    camera = CameraSettings(projector_on=True, exposure_us=3000.0, gain=32.0, auto_exposure=False)
    capture = {"ir": False, "ambient_frames": 5, "keep_raw": True}
    assert steps(plan) == [
        Home(), Configure(camera),
        *stop(1.0, "1.000m", 20, 0.0, **capture), *stop(0.5, "0.500m", 20, 0.0, **capture),
        *stop(2.125, "2.125m", 20, 0.0, **capture),
    ]  # a settle of 0 s is still a step: the runner adds up the settling before each capture


def test_the_old_name_frames_gives_frames_per_stop():
    assert steps(perpendicular([1.0], frames=7)) == [Home(), Configure(DEFAULT_CAMERA), *stop(1.0, "1.000m", 7)]


def test_a_warm_up_comes_after_the_settings_and_before_the_first_move():
    plan = perpendicular([1.0, 0.5], frames_per_stop=20, warm_up_drift_mm_per_min=0.2, warm_up_window_s=90,
                         warm_up_max_s=1200)
    assert steps(plan) == [Home(), Configure(DEFAULT_CAMERA), WarmUp(0.2, 90.0, 1200.0),
                           *stop(1.0, "1.000m", 20), *stop(0.5, "0.500m", 20)]
    assert steps(perpendicular([1.0], warm_up_window_s=90)) == [Home(), Configure(DEFAULT_CAMERA), *stop(1.0, "1.000m")]


@pytest.mark.parametrize("stops,message", [
    ([], "no stops given"),
    ([1.0, 1.0004], "repeats a distance (to the mm)"),
    ("1.0", "must be a list of distances in m"),
])
def test_stops_that_cannot_be_a_plan_are_refused_when_it_is_made(stops, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        perpendicular(stops)


# --- tilted --------------------------------------------------------------------------------------------


def test_the_default_tilted_plan_step_by_step():
    plan = tilted()
    assert plan.name == "tilted" and plan.stops_param == "distance_m"
    assert steps(plan) == TILTED_DEFAULT
    assert (plan.params["tilt_deg"], plan.params["distance_m"], plan.params["frames_per_stop"]) == (31.0, 0.8, 600)


def test_the_tilt_is_the_walls_and_moves_nothing():
    # the tilt places the (simulated) wall; the stage goes to distance_m whatever the tilt
    assert steps(tilted(tilt_deg=10.0, distance_m=1.5, frames=60)) == \
        steps(tilted(tilt_deg=45.0, distance_m=1.5, frames_per_stop=60)) == \
        [Home(), Configure(DEFAULT_CAMERA), *stop(1.5, "tilted", frames=60)]


def test_a_tilted_run_warms_up_before_its_one_stop():
    assert steps(tilted(distance_m=1.5, frames_per_stop=60, warm_up_drift_mm_per_min=1)) == \
        [Home(), Configure(DEFAULT_CAMERA), WarmUp(1.0, 60.0, 1800.0), *stop(1.5, "tilted", frames=60)]


def test_a_tilt_beyond_the_range_is_refused_when_the_plan_is_made():
    with pytest.raises(ValueError, match="tilt_deg"):
        tilted(tilt_deg=80.0)


# --- every protocol in the catalogue -------------------------------------------------------------------


def test_every_built_in_protocol_has_its_steps_written_out_here():
    assert [spec.name for spec in BUILT_IN] == list(EXPECTED_DEFAULT)


@pytest.mark.parametrize("name", protocol_names())
def test_each_protocol_in_the_catalogue_is_a_plain_list_of_steps(name):
    spec = protocol_spec(name)
    plan = spec.plan()
    got = steps(plan)
    assert got == steps(plan), "steps() must make the same steps afresh each time (the runner reads them twice)"
    assert got and all(isinstance(s, (Home, Configure, Move, Settle, Capture)) for s in got), got
    captures = [s for s in got if isinstance(s, Capture)]
    assert captures and plan.captures() == captures
    assert len({c.stop for c in captures}) == len(captures), "stop labels must be unique: a resume skips by label"
    assert all(c.n_frames == spec.frames_per_stop for c in captures)
    first_capture = got.index(captures[0])
    assert any(isinstance(s, Configure) for s in got[:first_capture]), "the camera is configured before capturing"
    moves = [s for s in got if isinstance(s, Move)]
    if moves:  # a serial stage refuses to move before it is homed
        assert any(isinstance(s, Home) for s in got[:got.index(moves[0])]), "the stage is homed before it moves"
    assert list(plan.params) == spec.names() and plan.stops_param == spec.stops_param
    if name in EXPECTED_DEFAULT:
        assert got == EXPECTED_DEFAULT[name]


# --- resuming: the plan's part ---------------------------------------------------------------------------


def test_more_stops_keep_the_labels_of_the_recorded_ones():
    first = perpendicular([0.5, 0.75, 1.0])
    longer = perpendicular([0.5, 0.75, 1.0, 1.25, 1.5])
    assert [c.stop for c in longer.captures()][:3] == [c.stop for c in first.captures()]
    assert resume_problems("perpendicular", first.params, longer, recorded={"0.500m", "0.750m"}) == []


def test_a_resumed_plan_may_not_drop_or_change_a_recorded_stop():
    first = perpendicular([0.5, 0.75, 1.0])
    dropped = resume_problems("perpendicular", first.params, perpendicular([0.5, 1.0]), recorded={"0.750m"})
    assert len(dropped) == 1 and "stop 0.750m is recorded but stops_m now leaves it out" in dropped[0]
    other_frames = resume_problems("perpendicular", first.params, perpendicular([0.5, 0.75, 1.0], frames_per_stop=30),
                                   recorded={"0.500m"})
    assert other_frames == ["plan frames_per_stop 300 in the file, 30 now"]
    assert resume_problems("perpendicular", first.params, tilted(), recorded={"0.500m"}) == \
        ["protocol 'perpendicular' in the file, 'tilted' now"]
