"""The docs quote the benchmark's figures only through docs/performance.md's table, which is generated from
benchmark-results.json (`python -m benchmarks.table`): the table must be the file's, to the character."""

import json

import pytest

from benchmarks.table import BEGIN, DOC, END, RESULTS, block, figures_of, rewrite

FIX = "run `python -m benchmarks.table`"


def test_the_performance_table_is_the_benchmark_files():
    text = DOC.read_text()
    if text.count(BEGIN) != 1 or text.count(END) != 1:
        pytest.fail(f"docs/performance.md needs one {BEGIN} ... {END} block; {FIX}", pytrace=False)
    if rewrite(text, json.loads(RESULTS.read_text())) != text:
        pytest.fail(f"docs/performance.md's table differs from benchmark-results.json: {FIX}", pytrace=False)


def test_a_figure_that_moves_is_found():
    """The check above would see one figure changed in the file (its seconds, or whether it passed)."""
    doc = json.loads(RESULTS.read_text())
    assert figures_of(doc), "benchmark-results.json holds no figures"
    moved = json.loads(json.dumps(doc))
    moved["figures"][0]["ours"] *= 1.5
    assert block(moved) != block(doc)
    moved = json.loads(json.dumps(doc))
    moved["figures"][0]["passed"] = not moved["figures"][0]["passed"]
    assert block(moved) != block(doc)


def test_a_page_without_markers_is_refused():
    with pytest.raises(ValueError, match="no block"):
        rewrite("# Performance\n", json.loads(RESULTS.read_text()))
