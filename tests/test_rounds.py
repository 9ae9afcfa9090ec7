"""The one round driver (bayescalib.inference.rounds) through every store and evaluator.

Specification: a problem calibrated in rounds gives the same rounds, value for value,
whether the rounds' products live in memory or in files and whether the points are
evaluated by a Python function or by the solve path (one isolated solve per point, its
run record, discrepancy and log-likelihood). The workflow's own rounds are checked
against the driver in ``tests/test_workflow_active.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from bayescalib.config import merge_layers
from bayescalib.inference.rounds import (
    Evaluations,
    LoglikFunction,
    MemoryStore,
    OutputsFunction,
    RoundSettings,
    run_rounds,
)
from bayescalib.stages.chain import FileStore, SolvePath
from bayescalib.stages.files import _clean
from bayescalib.stages.observe import observe
from bayescalib.study import Study

DATA = Path(__file__).parent / "data"

# small rounds: 8 initial points, batches of 3 (+1 check point), a check round of 4 draws
ACTIVE = {"n_initial": 8, "batch_size": 3, "max_solves": 24, "seed": 2}
CHECK = {"draws": 4}


@pytest.fixture(scope="module")
def analytic(tmp_path_factory):
    """The analytic stand-in model of tests/data/analytic_study.yaml (a python forward
    model), failing below E = 250 Pa (a fifth of the box: failed solves in round 0), and
    its synthetic observations."""
    cfg = yaml.safe_load((DATA / "analytic_study.yaml").read_text())
    cfg["forward_model"]["python"]["options"]["fail_below_E"] = 250.0
    cfg["design"] = {"strategy": "active", "seed": 1, "active": ACTIVE}
    cfg["posterior_check"] = CHECK
    cfg["surrogate"] = {"restarts": 1, "reselect_growth": 0.5}
    study = Study(merge_layers([cfg]))
    c = study.config
    tmp = tmp_path_factory.mktemp("rounds")
    from bayescalib.models.forward import solve_point

    solve_point(study.forward_section(), study.ground_truth_point(), tmp / "truth.h5",
                isolate=False)
    observe(c["observations"], tmp / "obs.h5", ground_truth_run=tmp / "truth.h5")
    return study, tmp


def _solve_path(study, obs: Path, workdir: Path) -> SolvePath:
    c = study.config
    return SolvePath(study.forward_section(), c["parameters"], obs, "rkhs", c["measure"],
                     c["likelihood"], workdir)


class _Replay:
    """Evaluates a point by looking up its evaluation among recorded ones: the values
    the solve path gave, as a Python function would give them."""

    def __init__(self, rows: Evaluations) -> None:
        self.rows = rows

    def __call__(self, X: np.ndarray) -> Evaluations:
        idx = [int(np.flatnonzero(np.all(self.rows.X == x, axis=1))[0]) for x in X]
        return self.rows.take(np.asarray(idx))


def _records(rounds) -> list:
    return json.loads(json.dumps(_clean(rounds)))


def test_every_store_and_evaluator_runs_the_same_rounds(analytic, tmp_path):
    study, tmp = analytic
    settings = RoundSettings.from_config(study.config)
    space = study.space
    X0 = study._design[: ACTIVE["n_initial"]]

    solve = _solve_path(study, tmp / "obs.h5", tmp_path / "files_solve")
    files_solve = run_rounds(solve, FileStore(tmp_path / "files_solve", study.config["parameters"],
                                              settings), settings, X0)
    reference = _records(files_solve.rounds)
    assert len(reference) >= 3 and files_solve.rows.status.min() == 0  # a failed solve in it
    assert any(r["posterior_check"] for r in reference)  # a check round was judged
    replay = _Replay(files_solve.rows)
    runs = {
        "memory, function": run_rounds(replay, MemoryStore(space, settings), settings, X0),
        "files, function": run_rounds(
            replay, FileStore(tmp_path / "files_fn", study.config["parameters"], settings),
            settings, X0),
        "memory, solve path": run_rounds(_solve_path(study, tmp / "obs.h5", tmp_path / "mem"),
                                         MemoryStore(space, settings), settings, X0),
    }
    for name, res in runs.items():
        assert _records(res.rounds) == reference, name
        np.testing.assert_array_equal(res.smc.particles, files_solve.smc.particles, err_msg=name)
        assert res.fit == files_solve.fit, name
    # the file store laid each round out as the workflow does
    for r in range(len(reference)):
        for f in ("training.h5", "surrogate.h5", "particles.h5", "acquire.json"):
            assert (tmp_path / "files_solve" / "active" / str(r) / f).is_file()


def test_a_loglik_function_and_its_outputs_evaluate_alike():
    """OutputsFunction: residuals U - y in noise units and loglik = offset - |U - y|^2/2;
    LoglikFunction: the values as given, NaN read as a failure; both record the bound
    and the measurements of the evaluations that succeeded only."""
    y = np.array([1.0, -2.0])
    outs = OutputsFunction(lambda X: np.column_stack([X[:, 0], X[:, 0] * X[:, 1]]), y, 3.0)
    X = np.array([[1.0, -2.0], [np.nan, 0.0], [0.0, 1.0]])
    ev = outs(X)
    np.testing.assert_array_equal(ev.status, [1, 0, 1])
    assert ev.loglik[0] == 3.0 and ev.loglik[1] == -np.inf
    assert ev.loglik[2] == pytest.approx(3.0 - 0.5 * (1.0 + 4.0))
    np.testing.assert_array_equal(ev.bound, [3.0, np.nan, 3.0])
    np.testing.assert_array_equal(ev.n_measurements, [2.0, np.nan, 2.0])
    assert np.all(np.isnan(ev.residuals[1]))
    lf = LoglikFunction(lambda X: np.array([0.0, np.nan, -1.0]), bound=0.5, n_measurements=7)
    ev = lf(X)
    np.testing.assert_array_equal(ev.loglik, [0.0, -np.inf, -1.0])
    np.testing.assert_array_equal(ev.bound, [0.5, np.nan, 0.5])
    assert ev.residuals.shape == (3, 0) and ev.reason == ("", "", "")


def test_evaluations_concatenate_with_residuals_of_unequal_width():
    """Rows without residual vectors (m = 0, e.g. an older table) and rows with them:
    the joined rows keep the wider width, NaN where none was recorded; take and
    with_columns keep every column aligned."""
    a = LoglikFunction(lambda X: -np.sum(X ** 2, 1), bound=0.0)(np.ones((2, 2)))
    b = OutputsFunction(lambda X: X, np.zeros(2))(np.zeros((3, 2)))
    ab = a + b
    assert len(ab) == 5 and ab.residuals.shape == (5, 2)
    assert np.all(np.isnan(ab.residuals[:2])) and np.all(ab.residuals[2:] == 0.0)
    sub = ab.take(np.array([True, False, True, False, True]))
    assert len(sub) == 3 and sub.reason == ("", "", "")
    np.testing.assert_array_equal(sub.loglik, ab.loglik[[0, 2, 4]])
    ext = sub.with_columns(np.array([0.0, 5.0]))
    assert ext.X.shape == (3, 4) and np.all(ext.X[:, 3] == 5.0)
    assert len(Evaluations.empty(2) + a) == 2
