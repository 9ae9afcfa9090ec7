"""Failed solves as an infeasible region (bayescalib.inference.feasibility), as
specifications: the neighbour rule's geometry on cases drawn by hand, which failures
count, and the surrogate that carries them."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from bayescalib.inference.feasibility import (
    FailedRegion,
    failure_radii,
    fit_targets,
    marks_infeasible,
    says_nothing_of_the_model,
)
from bayescalib.inference.gp import GPSurrogate, fit_gp


def test_a_failure_amid_solves_marks_its_voronoi_cell_and_nothing_else():
    ok = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    region = FailedRegion(ok, [[0.5, 0.5]])
    assert region.radii == pytest.approx([np.sqrt(0.5)])
    inside = [[0.5, 0.5], [0.6, 0.4], [0.74, 0.5]]  # nearer the failure than any corner
    outside = [[0.9, 0.9], [0.0, 0.0], [0.2, 0.1]]
    assert region.contains(inside).all()
    assert not region.contains(outside).any()
    assert not region.contains([[0.25, 0.25]])[0]  # a tie counts as feasible


def test_the_solves_themselves_are_classified_exactly():
    rng = np.random.default_rng(0)
    U = rng.uniform(size=(40, 3))
    failed = U[:, 0] > 0.7
    region = FailedRegion(U[~failed], U[failed])
    np.testing.assert_array_equal(region.contains(U), failed)


def test_a_failure_at_the_edge_reaches_no_farther_than_its_nearest_solve():
    """Beyond a failure at the edge no solve bounds its cell; the radius (its distance
    to the nearest solve) does, so one failure cannot close the rest of the box."""
    region = FailedRegion([[0.0, 0.5]], [[0.4, 0.5]])
    assert region.radii == pytest.approx([0.4])
    assert region.contains([[0.3, 0.5], [0.79, 0.5]]).all()
    assert not region.contains([[0.81, 0.5], [1.0, 0.5], [0.1, 0.5]]).any()
    assert failure_radii(np.empty((0, 2)), [[0.4, 0.5]]) == pytest.approx([np.inf])


@pytest.mark.parametrize("reason, machine", [
    ("loading load_0: wall-clock time limit reached", True),
    ("command exceeded its time limit of 60 s (killed)", True),
    ("killed after exceeding the time limit (90 s)", True),
    ("solver process died (exit code -11)", True),
    ("command could not be started: [Errno 2] No such file", True),
    ("loading load_1: load continuation stalled: inverted element: min det F = -0.19", False),
    ("Newton did not converge in 30 iterations", False),
    ("interface contains NaN or inf", False),
    ("command exited with status 1", False),
    ("ValueError: E must be positive", False),
])
def test_only_failures_that_depend_on_the_parameters_mark_a_region(reason, machine):
    assert says_nothing_of_the_model(reason) is machine
    # a solved point marks nothing, whatever its reason field holds
    np.testing.assert_array_equal(marks_infeasible([False, True], [reason, reason]),
                                  [not machine, False])


def _misfit(X):
    return -0.5 * np.sum(((np.atleast_2d(X) - 0.5) / 0.2) ** 2, axis=1)


def test_the_surrogate_keeps_its_failed_points_through_a_file_and_nan_marks_none(tmp_path):
    bounds = np.array([[0.0, 1.0], [0.0, 1.0]])
    X = np.random.default_rng(1).uniform(size=(20, 2))
    L = _misfit(X)
    L[[0, 1]] = -np.inf  # the model cannot be solved there
    L[2] = np.nan  # a time limit: no value, no region
    gp = fit_gp(X, L, bounds=bounds, bound=0.0,
                warp=True, restarts=1,
                kernel="matern32", nugget="fixed", mean="constant", ard=False)
    assert gp.n_excluded == 3 and gp.n_failed == 2
    np.testing.assert_array_equal(gp.X_failed, X[[0, 1]])
    assert gp.infeasible(X[[0, 1]]).all() and not gp.infeasible(X[2:]).any()
    gp.save(tmp_path / "s.h5")
    back = GPSurrogate.load(tmp_path / "s.h5")
    np.testing.assert_array_equal(back.X_failed, gp.X_failed)
    P = np.random.default_rng(2).uniform(size=(300, 2))
    np.testing.assert_array_equal(back.loglik(P), gp.loglik(P))
    with h5py.File(tmp_path / "s.h5", "a") as f:  # a file written before failures were kept
        del f["X_failed"]
    old = GPSurrogate.load(tmp_path / "s.h5")
    assert old.X_failed is None
    np.testing.assert_array_equal(old.loglik(P), old.predict(P))


def test_the_surrogate_leaves_out_machine_failures_and_keeps_the_model_s():
    """fit_targets: values kept; a time limit (the machine's) becomes NaN and is left out;
    a solver failure stays -inf and marks the infeasible region."""
    y = fit_targets(np.array([-1.5, -np.inf, -np.inf]),
                    ["", "killed after exceeding the time limit (90 s)", "Newton diverged"])
    assert y[0] == -1.5 and np.isnan(y[1]) and y[2] == -np.inf
