"""Lambda from fewer than three ranges, or from a span under 1.5 x, is NOT DETERMINED (rig.models.data.determinacy):
said with the reason and the fix by fit, compare and diagnose, never called "within noise", exit status 3."""

from pathlib import Path

import pytest
from cli_in_process import rig_in_process as rig

from rig.models import ModelData
from rig.models.data.determinacy import lambda_status
from simrig import record_perpendicular

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def recordings(tmp_path_factory, small_recording) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("undetermined")
    out = {"four": small_recording}
    for name, stops in (("one", [1.0]), ("narrow", [1.0, 1.1, 1.2])):
        out[name] = record_perpendicular(folder / f"{name}.h5", width=32, frames=8, stops_m=stops)[0]
    return out


def test_the_rule(recordings, tmp_path):
    one = lambda_status(ModelData.from_recording(recordings["one"]))
    assert not one.determined and one.n_ranges == 1 and "one range (1.000 m)" in one.reason
    assert "--model active" in one.fix and "wider range" in one.fix
    narrow = lambda_status(ModelData.from_recording(recordings["narrow"]))
    assert narrow.n_ranges == 3 and narrow.span == pytest.approx(1.2, abs=0.01) and not narrow.determined
    assert "a span of 1.20 x" in narrow.reason
    four = ModelData.from_recording(recordings["four"])
    assert lambda_status(four).determined and lambda_status(four).n_ranges == 4
    assert not lambda_status(four.in_range(0.9, 1.1)).determined  # a window holding one stop
    assert lambda_status(ModelData.from_recording(recordings["one"]), free=False).determined  # lambda fixed: no question
    from rig.cli import main

    tilted = tmp_path / "tilted.h5"  # one stop of a tilted wall spans a range of its own
    assert main(["-q", "run", "--protocol", "tilted", "--tilt-deg", "31", "--frames", "4", "--camera", "fake:width=32",
                 "-o", str(tilted)]) == 0
    status = lambda_status(ModelData.from_recording(tilted))
    assert status.determined and status.n_ranges >= 3 and status.span >= 1.5


@pytest.mark.parametrize("which,window", [("one", []), ("four", ["--z-min", "0.9", "--z-max", "1.1"]), ("narrow", [])])
def test_fit_says_not_determined_with_the_fix_and_exits_3(recordings, which, window):
    r = rig("fit", recordings[which], *window)
    assert r.returncode == 3, r.stderr
    assert "lambda NOT DETERMINED: the fitted pixels lie at" in r.stdout
    assert "to determine lambda: record more stops" in r.stdout and "--model active" in r.stdout
    assert "within noise" not in r.stdout


def test_a_fixed_lambda_is_an_answer(recordings):
    r = rig("fit", recordings["one"], "--model", "active", "--no-held-out")
    assert r.returncode == 0 and "NOT DETERMINED" not in r.stdout


def test_compare_and_diagnose_say_which_lambda_is_not_determined(recordings, tmp_path):
    r = rig("compare", recordings["four"], "--models", "active,power_law", "--z-min", "0.9", "--z-max", "1.1", "--no-held-out")
    assert r.returncode == 3, r.stderr
    rows = {line.split()[0]: line for line in r.stdout.splitlines() if line.startswith(("active ", "power_law "))}
    assert rows["power_law"].split()[-2:] == ["determined", f"{float(rows['power_law'].split()[-1]):.1f}"]
    assert "not determined" in rows["power_law"] and rows["active"].split()[6] in ("yes", "no")
    assert "power_law: lambda is not determined" in r.stdout
    d = rig("diagnose", recordings["one"], "--out", tmp_path / "d")
    assert d.returncode == 0, d.stderr  # the diagnosis starts from active, whose lambda is fixed
    assert "the paper's free power law: lambda = " in d.stdout and "; NOT DETERMINED: the fitted pixels lie at one range" in d.stdout


def test_a_stops_range_is_its_median_whether_made_here_or_given():
    """`distinct_ranges_m` takes each flat stop's median from `ModelData.median_range_by_stop` when given: the same
    ranges as numpy's median of the stop's positive finite ranges, for flat, tilted and NaN-holding stops."""
    import numpy as np

    from rig.models.data.determinacy import distinct_ranges_m

    rng = np.random.default_rng(5)
    flat = [rng.normal(z, 0.002, 400 + i) for i, z in enumerate((0.5, 0.75, 1.0, 1.6))]  # odd and even counts
    tilted = np.exp(rng.uniform(np.log(1.8), np.log(2.6), 900))
    holed = rng.normal(3.0, 0.003, 300)
    holed[::7] = np.nan
    z = np.concatenate([*flat, tilted, holed])
    stop = np.repeat(np.arange(6), [len(g) for g in (*flat, tilted, holed)])
    d = ModelData(z_m=z, m2_m2=np.ones_like(z), m4_m4=np.ones_like(z), n=np.full_like(z, 10.0), stop=stop)
    given = distinct_ranges_m(z, stop, d.stop_slices(), d.median_range_by_stop)
    assert given == distinct_ranges_m(z, stop, d.stop_slices()) == distinct_ranges_m(z, stop)
    expected = [float(np.median(g)) for g in flat] + [float(np.median(holed[np.isfinite(holed)]))]
    assert set(expected) <= set(given)  # each flat stop at its median exactly; the tilted one adds its steps
    assert len(given) > len(expected) and all(1.8 / 1.05 < r < 2.6 * 1.05 for r in set(given) - set(expected))
