"""bench_active.py's seed selection and its spread over seeds, as specifications."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
bench = pytest.importorskip("bench_active")


def test_seeds_per_problem_size_with_ranges_and_a_default():
    s = bench._parse_seeds("2d=0-4;7d=0,2", repeats=1)
    assert s == {2: [0, 1, 2, 3, 4], 7: [0, 2], None: [0]}
    assert bench._parse_seeds("1,3-4", repeats=5) == {None: [1, 3, 4]}
    assert bench._parse_seeds(None, repeats=3) == {None: [0, 1, 2]}


def test_the_summary_gives_the_median_the_range_over_seeds_and_how_many_converged():
    runs = [{"status": "ok", "mean_err": v, "converged": c}
            for v, c in ((0.3, True), (0.1, False), (0.2, True))]
    s = bench.summarize(runs)
    assert s["mean_err"] == pytest.approx(0.2)
    assert s["mean_err_range"] == [pytest.approx(0.1), pytest.approx(0.3)]
    assert s["n_converged"] == "2/3"
    one = bench.summarize(runs[:1])
    assert "mean_err_range" not in one and "n_converged" not in one
