"""The benchmark's figures over several runs (`python -m benchmarks --repeat N`): each run's ratio is against the
baseline measured in that run, and the reported ratio is the median of those, not a ratio of medians taken from
different runs."""

from benchmarks.figures import Figure, median_of_runs


def _run(ours: float, baseline: float) -> list[Figure]:
    return [Figure("rig fit", ours, baseline, "s", "< 2 s", ours < 2.0, "the paper's script")]


def test_the_ratio_of_several_runs_is_the_median_of_each_runs_own():
    runs = [_run(3.0, 1.8), _run(4.4, 1.7), _run(4.1, 2.2)]  # ratios 1.667, 2.588, 1.864
    (f,) = median_of_runs(runs)
    assert f.ours == 4.1 and f.baseline == 1.8  # the medians of each, as measured
    assert abs(f.ratio - 4.1 / 2.2) < 1e-12  # the middle run's own ratio; 4.1 / 1.8 = 2.28 would pair two runs
    assert "1.67, 2.59, 1.86" in f.note
    assert [r["ours"] for r in f.extra["runs"]] == [3.0, 4.4, 4.1]


def test_one_run_is_reported_as_it_is():
    (f,) = median_of_runs([_run(3.0, 1.5)])
    assert f.ratio == 2.0 and f.note == ""
