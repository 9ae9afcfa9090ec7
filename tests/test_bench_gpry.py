"""bench_active.py's GPry wrapper (the optional peer of the active design), as specifications.

GPry (pip package ``gpry``) is an optional benchmark dependency (``pip install -e '.[bench]'``),
not in CI's install: the test that runs it is skipped where it does not import, and marked
slow (``pytest -m slow tests/test_bench_gpry.py``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
bench = pytest.importorskip("bench_active")

MEAN = np.array([0.3, -0.2])
SD = np.array([0.2, 0.3])


def _gauss2d() -> bench.Problem:
    # the box [-2, 2]^2 lies more than 6 sd from the mean: truncation moves no moment visibly
    return bench.Problem(
        name="gauss2d", names=["a", "b"], bounds=np.array([[-2.0, 2.0], [-2.0, 2.0]]),
        loglik=lambda X: -0.5 * np.sum(((np.atleast_2d(X) - MEAN) / SD) ** 2, axis=1),
        B=0.0, ref_mean=MEAN, ref_cov=np.diag(SD**2),
    )


def test_without_gpry_the_benchmark_says_it_is_not_installed(monkeypatch):
    monkeypatch.setitem(sys.modules, "gpry", None)  # import gpry raises ImportError
    with pytest.raises(bench.NotAvailable, match="not installed"):
        bench.run_gpry(_gauss2d(), budget=16, seed=0)


@pytest.mark.slow  # about 3 min on a loaded 2-core machine: GPry runs a nested sampler every other batch
def test_gpry_recovers_a_2d_gaussian_within_its_budget():
    pytest.importorskip("gpry", reason="GPry (optional benchmark peer: pip install gpry) not installed")
    budget = 24
    out = bench.run_gpry(_gauss2d(), budget=budget, seed=0)
    # the evaluations are counted by a wrapper of the likelihood, and stay within the budget
    assert 6 <= out["n_evals"] <= budget
    assert out["extra"]["mc_evals_after_run"] == 0  # sampling the surrogate costs no evaluation
    assert out["n_rounds"] == out["extra"]["n_initial_blocks"] + out["extra"]["n_acquisition_batches"]
    m, C = bench.weighted_moments(out["samples"], out["weights"])
    sd = np.sqrt(np.diag(C))
    # a GP of a Gaussian log-likelihood from ~20 points: mean within 0.1 sd, sd within 10 %
    # (the 20 000 SMC draws alone are good to about 0.01 sd)
    assert np.all(np.abs(m - MEAN) < 0.1 * SD), (m, MEAN)
    assert np.all(np.abs(sd / SD - 1) < 0.10), (sd, SD)
    assert out["samples"].shape == (bench.GPRY_SMC_PARTICLES, 2)
    # GPry's own nested sample of the same surrogate agrees, within its smaller effective size
    own = out["extra"]["own_sample"]
    assert own["mean_err"] < 0.25 and own["sd_err"] < 0.25, own
    # the 2D metric: its surrogate log-posterior on the benchmark grid is a density there
    G = np.array([[0.3, -0.2], [1.9, 1.9]])
    lp = out["grid_logpdf"](G)
    assert lp.shape == (2,) and np.isfinite(lp[0]) and (lp[0] > lp[1])
