"""Frames checked for independence: the real OAK-D recording (filters on, repeated frames) gives one line, not a
fit; recordings without the lag-1 statistics read as "not checked"."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from drivers.folder import MANIFEST_NAME
from protocols.folder_import import import_folder
from protocols.recording import Recording
from rig.cli import main
from rig.models.data.independence import Independence, independence, pooled_lag1

pytestmark = pytest.mark.slow


OAKD = Path(__file__).resolve().parent / "vendor" / "real" / "oakd-filtered"
# the OAK-D recording did not save its intrinsics: these are made up (a 400P OAK-D is about fx 450 px at 640 wide)
MANIFEST = """# made-up intrinsics: the recording did not save them
fx = 450.0
fy = 450.0
cx = 320.0
cy = 180.0
baseline_m = 0.075
depth_unit_m = 0.001
projector_on = true
camera_model = "OAK-D (intrinsics made up for this test)"

[stop_distance_m]
"stop_0.55m" = 0.55
"""


@pytest.fixture(scope="module")
def oakd(tmp_path_factory) -> Path:
    if not (OAKD / "depth_01.npy").exists():
        pytest.skip(f"the real OAK-D frames are not at {OAKD}")
    root = tmp_path_factory.mktemp("oakd")
    stop = root / "frames" / "stop_0.55m"  # the scene's mean range is 0.556 m: the import checks the unit with it
    stop.mkdir(parents=True)
    for i in range(1, 11):
        (stop / f"depth_{i:02d}.npy").symlink_to(OAKD / f"depth_{i:02d}.npy")
    (root / "frames" / MANIFEST_NAME).write_text(MANIFEST)
    return import_folder(root / "frames", root / "oakd.h5")


@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_the_real_oakd_frames_give_one_line_naming_the_problem_and_the_fix(oakd, command, capsys):
    assert main([command, str(oakd)]) == 2
    out = capsys.readouterr()
    err = out.err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err and not out.out, (out.out, err)
    for needle in ("frames are not independent", "never change", "repeat the previous one", "no temporal noise to fit",
                   "without the camera's post-processing filters", "without duplicated frames"):
        assert needle in err, err


def test_the_oakd_recording_holds_its_lag1_statistics(oakd):
    with Recording(oakd) as rec:
        s = rec.stop(rec.stop_labels()[0]).stats
    assert s.frames_repeated == 7  # of 9 pairs of frames: the recorder saved few distinct frames
    num, den, pairs = pooled_lag1(s)
    assert pairs > 1e6 and num / den > 0.5


def test_a_recording_without_lag1_statistics_reads_as_not_checked(oakd, tmp_path):
    old = tmp_path / "old.h5"
    old.write_bytes(oakd.read_bytes())
    with h5py.File(old, "a") as f:
        for g in f["stops"].values():
            del g["lag1_pairs"], g["lag1_m2"]
            del g.attrs["frames_repeated"]
    with Recording(old) as rec:
        s = rec.stop(rec.stop_labels()[0]).stats
    assert s.lag1_pairs is None and s.lag1_m2 is None and s.frames_repeated is None
    assert np.isnan(pooled_lag1(s)[0])
    ind = independence(None)
    assert not ind.checked and "not checked" in ind.sentence() and ind.error_inflation == 1.0


def test_effective_frames_follow_bartlett_for_ar1():
    ind = Independence(rho=0.6, se=0.02, frames_repeated=0, frame_pairs=99, constant_share=0.0)
    # the formula with fl(0.6)^2 there and the decimal 0.36 here: each side a few roundings (the square, the
    # difference, the sum, the quotient; the decimal's own), within 8 u; the inflation's root and quotient add 2 u each
    u = np.finfo(np.float64).eps / 2
    assert ind.correlated and ind.n_eff_fraction == pytest.approx((1 - 0.36) / (1 + 0.36), rel=8 * u, abs=0)
    assert ind.error_inflation == pytest.approx(np.sqrt(1.36 / 0.64), rel=12 * u, abs=0)
    assert "0.60" in ind.sentence() and "temporal filter" in ind.sentence()
    assert not Independence(0.01, 0.02, 0, 99, 0.0).correlated


def test_a_temporal_filter_is_named_frames_not_independent_and_never_within_noise(tmp_path):
    """The fake camera's temporal post-filter (the blind test's temporal_filter scenario), small and without the
    diagnosis's path (a few CPU seconds): the lag-1 family is beyond noise and the words say why and what to do."""
    from rig.diagnosis import diagnose
    from rig.models import ModelData
    from rig.simulation.scenarios import hidden_scenario, record_scenario

    sc = hidden_scenario(1000, "temporal_filter", width=27, frames=40)
    alpha = sc.params["alpha"]
    path = record_scenario(sc, tmp_path / "tf.h5")
    dg = diagnose(ModelData.from_recording(path), max_steps=0, explain=False)
    ind = dg.independence
    assert ind.correlated and abs(ind.rho - (1 - alpha)) < 0.1, (ind, alpha)  # smoothing: rho_1 = 1 - alpha
    assert ind.error_inflation > 1.2
    worst = dg.model_headline.consistency.worst(extra=1)
    assert worst is not None and worst.name == "lag-1 correlation by stop"
    text = dg.summary()
    assert text.startswith("Frames not independent: lag-1 correlation") and "temporal filter" in text, text
    assert "Fix: record without" in text and not dg.final_headline.within_noise
    assert "within noise (headline" not in text
    from rig.analysis import fit_recording

    fit = fit_recording(path)  # rig fit says it too, with the widened errors
    assert any(n.startswith("Frames not independent: lag-1 correlation") for n in fit.notes), fit.notes


@pytest.mark.numeric
def test_the_pooled_lag1_sums_are_numpys_sums_by_their_definition():
    """`pooled_lag1` (one compiled pass) against numpy's sums over the pixels with a pair and two samples.

    The same terms formed the same way (v = M2 / (n - 1), p v / n: three roundings, C1 + that: one), added in two
    orders (N - 1 roundings each): each sum within u (3 sum |p v / n| + N sum |term|) of the exact one, two of them
    within twice that; relative to the first sum, whose terms C1 have either sign, that is 2.3e-12 here, above the
    1e-12 once asked. The sum of p v has positive terms, 2 (N + 2) u; the sum of pairs is of whole numbers, exact."""
    from types import SimpleNamespace

    rng = np.random.default_rng(6)
    shape = (37, 53)
    count = rng.integers(0, 30, shape).astype(np.uint32)
    pairs = np.minimum(rng.integers(0, 30, shape), np.maximum(count.astype(int) - 1, 0)).astype(np.uint32)
    m2, lag = rng.gamma(2.0, 1e-6, shape), rng.normal(0, 1e-6, shape)
    s = SimpleNamespace(count=count, lag1_pairs=pairs, m2_m2=m2, lag1_m2=lag)
    ok = (pairs > 0) & (count > 1)
    assert 0 < ok.sum() < ok.size
    n, p = count[ok].astype(float), pairs[ok].astype(float)
    v = m2[ok] / (n - 1)
    terms = lag[ok] + p * v / n
    num, den, total = pooled_lag1(s)
    u, k = np.finfo(np.float64).eps / 2, ok.sum()
    assert abs(num - np.sum(terms)) <= 2 * u * (3 * np.sum(np.abs(p * v / n)) + k * np.sum(np.abs(terms)))
    assert abs(den - np.sum(p * v)) <= 2 * (k + 2) * u * np.sum(p * v)
    assert total == np.sum(p)
    none = SimpleNamespace(count=count, lag1_pairs=np.zeros(shape, np.uint32), m2_m2=m2, lag1_m2=lag)
    assert pooled_lag1(none) == (0.0, 0.0, 0.0)
