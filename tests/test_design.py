"""Scrambled Sobol design (bayescalib.inference.design)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayescalib.inference.design import sobol_design, sobol_test_points

BOX = np.array([[100.0, 800.0], [-0.8, 0.5], [0.0, 110.0]])


@settings(max_examples=25, deadline=None)
@given(n1=st.integers(1, 300), extra=st.integers(0, 300), seed=st.integers(0, 2**31 - 1))
def test_prefix_property(n1, extra, seed):
    """The first n points never change when n grows (bitwise), powers of two or not."""
    a = sobol_design(BOX, n1, seed)
    b = sobol_design(BOX, n1 + extra, seed)
    assert np.array_equal(a, b[:n1])


def test_points_in_box_and_seeded():
    X = sobol_design(BOX, 256, 3)
    assert X.shape == (256, 3)
    assert np.all((X >= BOX[:, 0]) & (X < BOX[:, 1]))
    assert np.array_equal(X, sobol_design(BOX, 256, 3))
    assert not np.array_equal(X, sobol_design(BOX, 256, 4))


def test_power_of_two_balance():
    """For n = 2^m every 1D projection has exactly one point per interval of width 1/n."""
    n = 64
    U = (sobol_design(BOX, n, 0) - BOX[:, 0]) / (BOX[:, 1] - BOX[:, 0])
    for j in range(3):
        assert np.array_equal(np.sort(np.floor(U[:, j] * n)), np.arange(n))


def test_test_points_are_later_points_of_same_sequence():
    full = sobol_design(BOX, 150, 7)
    t = sobol_test_points(BOX, 100, 50, 7)
    assert np.array_equal(t, full[100:150])
    # held-out points never coincide with training points
    assert min(np.min(np.abs(full[:100] - p).sum(1)) for p in t) > 0


def test_bad_bounds():
    with pytest.raises(ValueError, match="lo < hi"):
        sobol_design(np.array([[1.0, 0.0]]), 4, 0)
    with pytest.raises(ValueError, match="shape"):
        sobol_design(np.array([1.0, 2.0]), 4, 0)


@settings(max_examples=40, deadline=None)
@given(d=st.integers(1, 12), n=st.integers(0, 700), seed=st.integers(0, 2**32 - 1))
def test_points_are_bitwise_scipys_scrambled_sobol(d, n, seed):
    """sobol_unit (NumPy alone, no scipy.stats import) gives scipy's points bit for bit."""
    import warnings

    from scipy.stats import qmc

    from bayescalib.inference.design import sobol_unit

    engine = qmc.Sobol(d=d, scramble=True, seed=np.random.default_rng(seed))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # balance properties of n not a power of two
        ref = engine.random(n) if n else np.empty((0, d))
    assert np.array_equal(sobol_unit(d, n, seed), ref)


@pytest.mark.parametrize("d,n,seed", [(2, 4096, 1), (7, 1025, 0), (30, 300, 5)])
def test_long_and_wide_sequences_are_scipys(d, n, seed):
    import warnings

    from scipy.stats import qmc

    from bayescalib.inference.design import sobol_unit

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = qmc.Sobol(d=d, scramble=True, seed=np.random.default_rng(seed)).random(n)
    assert np.array_equal(sobol_unit(d, n, seed), ref)


def test_design_does_not_import_scipy_stats():
    """The workflow builds the design inside Snakemake's DAG building: scipy.stats's
    import (1-1.8 s) would delay every job."""
    import subprocess
    import sys

    code = ("import sys; from bayescalib.inference.design import sobol_design; "
            "sobol_design([[0, 1], [2, 3]], 64, 1); print('scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                         text=True).stdout.split()[-1]
    assert out == "False"
