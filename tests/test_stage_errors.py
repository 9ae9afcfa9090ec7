"""Pipeline stages facing bad data: every case ends in a PipelineError that says
what to change (never a NumPy/h5py traceback), and a corrupt per-point file is
set aside so that rerunning the same snakemake command recomputes it.

Library level only (no Snakemake): the stages are called as the rule scripts
call them, on run records written by the analytic stand-in model.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bayescalib.config import validate
from bayescalib.io.runrecord import read_run
from bayescalib.models.forward import failed_result, solve_point
from bayescalib.stages.discrepancy import discrepancy
from bayescalib.stages.errors import PipelineError
from bayescalib.stages.files import write_json
from bayescalib.stages.gather import gather
from bayescalib.stages.observe import observe
from bayescalib.stages.surrogate import train_surrogate

ANALYTIC = {"type": "python", "python": {"function": "bayescalib.models.analytic:interface"}}
PARAMETERS = [
    {"name": "E", "unit": "Pa", "target": "E", "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0},
     "bounds": [100.0, 800.0]},
    {"name": "nu", "unit": "-", "target": "nu", "prior": {"type": "uniform", "lo": -0.8, "hi": 0.45},
     "bounds": [-0.8, 0.45]},
]
SURROGATE = validate({"surrogate": {"restarts": 1}}, "inference")["surrogate"]


def _observations(section):
    """A validated observations section (stages trust the validated config)."""
    from bayescalib.config import validate

    return validate({"observations": section}, "measures")["observations"]



def _points(n: int = 8) -> np.ndarray:
    rng = np.random.default_rng(3)
    return np.column_stack([rng.uniform(100, 800, n), rng.uniform(-0.8, 0.45, n)])


def _table(tmp_path, X, loglik, status=None):
    """Run records + discrepancy files -> training.h5 through the gather stage."""
    runs, discs = [], []
    for i, ((E, nu), ll) in enumerate(zip(X, loglik, strict=True)):
        ok = status is None or status[i]
        rp, dp = tmp_path / "runs" / f"{i}.h5", tmp_path / "disc" / f"{i}.json"
        params = {"E": float(E), "nu": float(nu)}
        if ok:
            solve_point(ANALYTIC, params, rp, isolate=False)
        else:
            from bayescalib.io.runrecord import write_run

            write_run(rp, failed_result(params, "Newton did not converge at load 0.4"))
        write_json(dp, {"status": "ok" if ok else "failed", "loglik": ll,
                          "D": None if ll is None else 1.0})
        runs.append(rp)
        discs.append(dp)
    out = tmp_path / "training.h5"
    gather(runs, discs, ["E", "nu"], ["E", "nu"], len(runs), out)
    return out


def _train(path, tmp_path, **surrogate):
    train_surrogate(path, {**SURROGATE, **surrogate}, PARAMETERS, tmp_path / "surrogate.h5")


def _assert_clean(exc_info):
    """A PipelineError raised without a chained library traceback."""
    assert isinstance(exc_info.value, PipelineError)
    exc = exc_info.value
    assert exc.__cause__ is None and (exc.__context__ is None or exc.__suppress_context__)


def test_all_design_points_failed(tmp_path):
    X = _points()
    tab = _table(tmp_path, X, [None] * 8, status=[False] * 8)
    with pytest.raises(PipelineError) as info:
        _train(tab, tmp_path)
    msg = str(info.value)
    assert "all 8 design points failed" in msg
    assert "Newton did not converge at load 0.4" in msg  # the reason seen
    assert "forward model settings" in msg and "bounds" in msg
    _assert_clean(info)


def test_all_loglikelihoods_minus_inf(tmp_path):
    tab = _table(tmp_path, _points(), [None] * 8)  # runs ok, every measure value -inf
    with pytest.raises(PipelineError, match="log-likelihood of -inf") as info:
        _train(tab, tmp_path)
    assert "sigma_n" in str(info.value)
    _assert_clean(info)


def test_too_few_successes(tmp_path):
    tab = _table(tmp_path, _points(), [-1.0, -2.0] + [None] * 6,
                 status=[True, True] + [False] * 6)
    with pytest.raises(PipelineError, match="only 2 of 8 .* increase design.n_train") as info:
        _train(tab, tmp_path)
    _assert_clean(info)


def test_duplicate_design_points(tmp_path):
    X = _points()
    X[5] = X[2]
    tab = _table(tmp_path, X, list(-np.arange(8.0)))
    with pytest.raises(PipelineError) as info:
        _train(tab, tmp_path)
    msg = str(info.value)
    assert "design points 2, 5 have the same parameter values" in msg
    assert f"E={X[2, 0]:g}" in msg and "delete" in msg
    _assert_clean(info)
    assert not (tmp_path / "surrogate.h5").exists()


def test_a_repeated_failed_point_is_no_duplicate(tmp_path):
    # failed runs are left out of training, so they cannot collide
    X = _points()
    X[5] = X[2]
    status = [True] * 8
    status[5] = False
    ll = list(-((X[:, 0] - 400) / 300) ** 2)
    ll[5] = None
    tab = _table(tmp_path, X, ll, status=status)
    _train(tab, tmp_path)
    assert (tmp_path / "surrogate.h5").is_file()


def test_gp_that_cannot_be_fitted(tmp_path):
    X = _points()
    # log-likelihood values near the float limit (e.g. a sigma_n2 of 1e-300): GPy fails
    ll = list(-1e300 * (1.0 + np.arange(8.0)))
    tab = _table(tmp_path, X, ll)
    with pytest.raises(PipelineError) as info:
        _train(tab, tmp_path)
    msg = str(info.value)
    assert "GP surrogate cannot be fitted" in msg
    for key in ("surrogate.restarts", "surrogate.optimizer", "surrogate.nugget_factor",
                "likelihood.sigma_n2"):
        assert key in msg
    _assert_clean(info)
    assert not (tmp_path / "surrogate.h5").exists()


# ------------------------------------------------------------------ corrupt per-point files
@pytest.fixture()
def observed(tmp_path):
    truth = tmp_path / "obs" / "truth.h5"
    solve_point(ANALYTIC, {"E": 400.0, "nu": 0.3}, truth, isolate=False)
    obs = tmp_path / "obs" / "observations.h5"
    observe(_observations({"source": "synthetic"}), obs, ground_truth_run=truth)
    return obs


def _truncate(path):
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
def test_discrepancy_sets_a_corrupt_run_record_aside(tmp_path, observed, damage):
    run = tmp_path / "runs" / "3.h5"
    solve_point(ANALYTIC, {"E": 500.0, "nu": 0.2}, run, isolate=False)
    if damage == "truncate":
        _truncate(run)
    elif damage == "garbage":
        run.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0garbage" * 50)
    else:
        run.write_bytes(b"")
    out = tmp_path / "disc" / "3.json"
    with pytest.raises(PipelineError) as info:
        discrepancy(run, observed, "rkhs", {"sigma_w": 0.005},
                      {"sigma_n2": 0.0005}, out)
    msg = str(info.value)
    assert "runs/3.h5" in msg and "moved to" in msg
    assert "Run the same snakemake command again" in msg
    _assert_clean(info)
    assert not run.exists() and (tmp_path / "runs" / "3.h5.corrupt").is_file()
    assert not out.exists()
    # once re-solved (what the next snakemake run does: the record is missing) all is well
    solve_point(ANALYTIC, {"E": 500.0, "nu": 0.2}, run, isolate=False)
    rec = discrepancy(run, observed, "rkhs", {"sigma_w": 0.005},
                        {"sigma_n2": 0.0005}, out)
    assert rec["loglik"] is not None


def test_gather_sets_a_corrupt_run_record_aside(tmp_path):
    X = _points(4)
    tab = _table(tmp_path, X, [-1.0, -2.0, -3.0, -4.0])
    tab.unlink()
    runs = [tmp_path / "runs" / f"{i}.h5" for i in range(4)]
    discs = [tmp_path / "disc" / f"{i}.json" for i in range(4)]
    _truncate(runs[1])
    with pytest.raises(PipelineError, match=r"runs/1.h5' is corrupt or truncated") as info:
        gather(runs, discs, ["E", "nu"], ["E", "nu"], 4, tab)
    _assert_clean(info)
    assert (tmp_path / "runs" / "1.h5.corrupt").is_file() and not tab.exists()


def test_gather_sets_a_corrupt_discrepancy_file_aside(tmp_path):
    X = _points(4)
    tab = _table(tmp_path, X, [-1.0, -2.0, -3.0, -4.0])
    runs = [tmp_path / "runs" / f"{i}.h5" for i in range(4)]
    discs = [tmp_path / "disc" / f"{i}.json" for i in range(4)]
    discs[2].write_text('{"status": "ok", "loglik": -1.')
    with pytest.raises(PipelineError, match=r"disc/2.json") as info:
        gather(runs, discs, ["E", "nu"], ["E", "nu"], 4, tab)
    assert "moved to" in str(info.value)
    assert (tmp_path / "disc" / "2.json.corrupt").is_file()


def test_gather_refuses_a_record_of_another_parameter_setup(tmp_path):
    X = _points(3)
    tab = _table(tmp_path, X, [-1.0, -2.0, -3.0])
    runs = [tmp_path / "runs" / f"{i}.h5" for i in range(3)]
    discs = [tmp_path / "disc" / f"{i}.json" for i in range(3)]
    with pytest.raises(PipelineError, match="no value for material.E") as info:
        gather(runs, discs, ["E", "nu"], ["material.E", "nu"], 3, tab)
    _assert_clean(info)


def test_observe_sets_a_corrupt_ground_truth_record_aside(tmp_path):
    truth = tmp_path / "truth.h5"
    solve_point(ANALYTIC, {"E": 400.0, "nu": 0.3}, truth, isolate=False)
    _truncate(truth)
    with pytest.raises(PipelineError, match="truth.h5") as info:
        observe(_observations({"source": "synthetic"}), tmp_path / "obs.h5", ground_truth_run=truth)
    _assert_clean(info)
    assert (tmp_path / "truth.h5.corrupt").is_file()


def test_a_good_table_still_trains(tmp_path):
    X = _points()
    ll = list(-((X[:, 0] - 400) / 300) ** 2 - ((X[:, 1] - 0.3) / 0.5) ** 2)
    tab = _table(tmp_path, X, ll)
    _train(tab, tmp_path)
    assert read_run(tmp_path / "runs" / "0.h5").status == "ok"
    assert json.loads((tmp_path / "disc" / "0.json").read_text())["loglik"] == ll[0]


def test_each_set_aside_gets_its_own_name(tmp_path, observed):
    """The gather rule lists the set-aside files: a second corruption of the same
    record must add a name (else the list would not change and nothing rerun)."""
    run = tmp_path / "runs" / "3.h5"
    for expected in ("3.h5.corrupt", "3.h5.1.corrupt", "3.h5.2.corrupt"):
        solve_point(ANALYTIC, {"E": 500.0, "nu": 0.2}, run, isolate=False)
        _truncate(run)
        with pytest.raises(PipelineError, match=expected.replace(".", r"\.")):
            discrepancy(run, observed, "rkhs", {"sigma_w": 0.005},
                          {"sigma_n2": 0.0005}, tmp_path / "d.json")
    assert sorted(p.name for p in run.parent.glob("*.corrupt")) == [
        "3.h5.1.corrupt", "3.h5.2.corrupt", "3.h5.corrupt"]


@pytest.mark.parametrize("scale, shift", [(1000.0, 0.0), (1.0e-3, 0.0), (1.0, 50.0)])
def test_observations_in_other_units_are_a_unit_slip_not_a_misfit(tmp_path, scale, shift):
    """Observed curves 1000x larger or smaller than the model's, or far away from it
    (metres or micrometres read as mm, a wrong origin), are refused with the likely
    cause, instead of giving a meaningless D."""
    from bayescalib.geometry.interface import Interface
    from bayescalib.io.observation_store import StoredObservations, write_observations

    truth = tmp_path / "truth.h5"
    res = solve_point(ANALYTIC, {"E": 400.0, "nu": 0.3}, truth, isolate=False)
    pts = np.asarray(res.interface_current) * scale + shift
    obs = tmp_path / "observations.h5"
    write_observations(obs, StoredObservations([Interface.polyline(pts)], ["scan"], [None], None,
                                               {"source": "files"}))
    with pytest.raises(PipelineError, match="unit slip") as exc:
        discrepancy(truth, obs, "rkhs", {"sigma_w": 0.005},
                      {"sigma_n2": 5e-4}, tmp_path / "d.json")
    _assert_clean(exc)
    assert "observations.files[].units" in str(exc.value)
    # the same curve in the right units is a normal discrepancy
    write_observations(obs, StoredObservations([Interface.polyline(np.asarray(
        res.interface_current))], ["scan"], [None], None, {"source": "files"}))
    rec = discrepancy(truth, obs, "rkhs", {"sigma_w": 0.005},
                        {"sigma_n2": 5e-4}, tmp_path / "d.json")
    assert rec["D"] == pytest.approx(0.0, abs=1e-9)


def test_the_output_emulator_refuses_a_table_without_residual_vectors(tmp_path):
    """surrogate.target outputs on a table gathered from records without distance
    vectors (an older run): a clear error naming the table and what to delete; the
    solves are kept."""
    X = _points()
    tab = _table(tmp_path, X, list(-np.arange(8.0)))
    with pytest.raises(PipelineError, match="holds no residual vectors") as info:
        _train(tab, tmp_path, target="outputs")
    assert str(tab) in str(info.value) and "solves are kept" in str(info.value)
    _assert_clean(info)
    assert all((tmp_path / "runs" / f"{i}.h5").is_file() for i in range(8))


def test_gather_refuses_residual_vectors_of_different_lengths(tmp_path):
    """Residual vectors of one measure must have one length (the same model interface
    and measure setup): otherwise gather names the records and lengths."""
    X = _points(3)
    _table(tmp_path, X, [-1.0, -2.0, -3.0])
    runs = [tmp_path / "runs" / f"{i}.h5" for i in range(3)]
    discs = [tmp_path / "disc" / f"{i}.json" for i in range(3)]
    for i, m in enumerate((5, 5, 7)):
        write_json(discs[i], {"status": "ok", "loglik": -1.0, "D": 1.0, "sigma_n2": 1e-6,
                              "snapshots": [{"n": m, "D": 1.0, "loglik": -1.0,
                                             "distances": [0.001] * m}]})
    with pytest.raises(PipelineError, match=r"differ in length \(5 in .*disc/0.json', 7 in "
                                            r".*disc/2.json'\)") as info:
        gather(runs, discs, ["E", "nu"], ["E", "nu"], 3, tmp_path / "t.h5")
    _assert_clean(info)
