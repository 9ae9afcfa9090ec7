"""One reader for every file a stage reads from another stage (bayescalib.stages.files.
read_stage_file), whatever its format: a file that cannot be read is moved aside to
``<name>.corrupt`` and the error names it, what it is, and says that the same snakemake
command rebuilds it, so the next run does (it is a missing target) instead of failing
on it again.

Each kind is truncated and read through the stage code that reads it, as the rule's job
calls it (library level; the workflow test of a truncated posterior.json rebuilt by the
next run is in tests/test_workflow.py)."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np
import pytest

from bayescalib.execution import jobserver
from bayescalib.inference.parameters import ParameterSpace
from bayescalib.inference.posterior import write_particles_h5
from bayescalib.inference.smc import SMCResult
from bayescalib.models.forward import solve_point
from bayescalib.stages import figures
from bayescalib.stages.errors import PipelineError
from bayescalib.stages.files import read_stage_file, write_json
from bayescalib.stages.gather import gather
from bayescalib.stages.observe import observe
from bayescalib.stages.summary import (
    design_summary,
    posterior_check_summary,
    round_posterior_check_summary,
    summary,
)
from bayescalib.stages.surrogate import train_surrogate

ANALYTIC = {"type": "python", "python": {"function": "bayescalib.models.analytic:interface"}}
PARAMETERS = [
    {"name": "E", "unit": "Pa", "target": "E", "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0},
     "bounds": [100.0, 800.0]},
    {"name": "nu", "unit": "-", "target": "nu", "prior": {"type": "uniform", "lo": -0.8, "hi": 0.45},
     "bounds": [-0.8, 0.45]},
]
PLOTS = {"formats": ["png"], "dpi": 40, "grid": 8}


def _truncate(path: Path) -> bytes:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return data[: len(data) // 2]


def _particles(path: Path) -> Path:
    x = np.column_stack([np.linspace(200, 700, 6), np.linspace(-0.5, 0.4, 6)])
    write_particles_h5(path, SMCResult(
        particles=x, weights=np.full(6, 1 / 6), loglik=np.zeros(6), logprior=np.zeros(6),
        log_evidence=-2.0, history={"beta": np.array([0.0, 1.0])}, n_steps=1),
        ParameterSpace.from_config(PARAMETERS))
    return path


def _assert_set_aside(info, path: Path, kind: str, cut: bytes) -> None:
    msg = str(info.value)
    assert isinstance(info.value, PipelineError)
    assert f"the {kind} '{path}' cannot be read" in msg, msg
    assert f"moved to '{path}.corrupt'" in msg, msg
    assert "Run the same snakemake command again" in msg, msg
    assert not path.exists() and Path(f"{path}.corrupt").read_bytes() == cut
    exc = info.value
    assert exc.__cause__ is None and exc.__suppress_context__  # no library traceback


# ------------------------------------------------------------------ JSON stage outputs
POSTERIOR = {"mean": {"E": 400.0, "nu": 0.3}, "std": {"E": 20.0, "nu": 0.05},
             "map": {"E": 401.0, "nu": 0.31}, "map_full": {"E": 401.0, "nu": 0.31},
             "intervals": {"E": {"0.9": [370.0, 430.0]}, "nu": {"0.9": [0.2, 0.4]}},
             "gaussian": {"names": ["E", "nu"]}}
ROUND = {"round": 0, "stop": True, "converged": True, "n_solves": 8, "n_failed": 0,
         "reason": "converged", "posterior": {"sd": [20.0, 0.05]}, "change": None,
         "trust": None, "posterior_check": None}


def _json_cases():
    """(kind, file name, content, the stage code that reads it: f(tmp_path, path))."""
    return [
        ("posterior summary", "rkhs/posterior.json", POSTERIOR,
         lambda tmp, p: figures.posterior_figures(
             _particles(tmp / "rkhs" / "particles.h5"), p, PARAMETERS, PLOTS,
             {f: tmp / "fig" / f for f in ("joint", "particles", "marginals", "pairs",
                                           "parallel")})),
        ("posterior summary", "rkhs/posterior.json", POSTERIOR,
         lambda tmp, p: figures.posterior_mean_point(p, PARAMETERS)),
        ("posterior summary", "rkhs/posterior.json", POSTERIOR,
         lambda tmp, p: summary("s", PARAMETERS, ["rkhs"], [p], [tmp / "t.h5"],
                                [tmp / "p.h5"], {}, tmp / "summary.json")),
        ("GP convergence record", "rkhs/convergence.json",
         {"n_train": [4, 8], "rel_error": [0.2, 0.1], "loo_rel_error": [0.3, 0.1]},
         lambda tmp, p: figures.convergence_figure(p, PLOTS, tmp / "fig" / "convergence")),
        ("posterior check", "rkhs/posterior_check.json", {"confirmed": True, "draws": []},
         lambda tmp, p: posterior_check_summary(p)),
        ("active round record", "active/0/acquire.json", ROUND,
         lambda tmp, p: design_summary("active", [p], 8)),
        ("active round record", "active/0/acquire.json", ROUND,
         lambda tmp, p: round_posterior_check_summary([p])),
        ("active round record", "active/0/acquire.json", ROUND,
         lambda tmp, p: figures.rounds_figure([p], [], tmp / "t.h5", PARAMETERS,
                                              {"stop": {"shift_tol": 0.3}}, PLOTS,
                                              tmp / "fig" / "rounds")),
        ("study summary", "summary.json", {"study": "s"},
         lambda tmp, p: read_stage_file(p, "study summary")),  # as the Snakefile's onsuccess
    ]


@pytest.mark.parametrize("kind, name, content, read", _json_cases(),
                         ids=[f"{c[0]}-{k}" for k, c in enumerate(_json_cases())])
def test_a_truncated_json_stage_output_is_set_aside(tmp_path, kind, name, content, read):
    path = tmp_path / name
    write_json(path, content)
    cut = _truncate(path)
    with pytest.raises(PipelineError) as info:
        read(tmp_path, path)
    _assert_set_aside(info, path, kind, cut)


def test_a_truncated_discrepancy_record_is_set_aside_by_gather(tmp_path):
    runs = [tmp_path / "runs" / f"{i}.h5" for i in range(2)]
    discs = [tmp_path / "discrepancy" / "rkhs" / f"{i}.json" for i in range(2)]
    for rp, dp, E in zip(runs, discs, (300.0, 500.0), strict=True):
        solve_point(ANALYTIC, {"E": E, "nu": 0.3}, rp, isolate=False)
        write_json(dp, {"status": "ok", "loglik": -1.0, "D": 1.0})
    cut = _truncate(discs[1])
    with pytest.raises(PipelineError) as info:
        gather(runs, discs, ["E", "nu"], ["E", "nu"], 2, tmp_path / "training.h5")
    _assert_set_aside(info, discs[1], "discrepancy record", cut)


def test_a_json_stage_output_that_is_not_an_object_is_set_aside(tmp_path):
    path = tmp_path / "rkhs" / "posterior.json"
    path.parent.mkdir()
    path.write_text("[1, 2]\n")
    with pytest.raises(PipelineError, match="not an object") as info:
        figures.posterior_mean_point(path, PARAMETERS)
    _assert_set_aside(info, path, "posterior summary", b"[1, 2]\n")


# ------------------------------------------------------------------ the other formats
@pytest.fixture
def job_logging(monkeypatch):
    """A job sets up its logging (handlers, excepthook): undone after the test."""
    monkeypatch.setattr(sys, "excepthook", sys.excepthook)
    logger = logging.getLogger("bayescalib")
    handlers = list(logger.handlers)
    yield
    for h in logger.handlers[len(handlers):]:
        h.close()
    logger.handlers[:] = handlers


def test_a_truncated_warm_start_state_is_set_aside_by_the_solve_job(tmp_path, job_logging):
    """The solve job reads its warm-start state before it solves: a damaged one is set
    aside (the base_state rule makes it again), not solved from by every design point."""
    state = tmp_path / "runs" / "base_state.state.npz"
    state.parent.mkdir()
    np.savez(state, state=np.linspace(0.0, 1.0, 5000), key=np.array("space"),
             parameters=np.array("{}"))
    cut = _truncate(state)
    out = tmp_path / "runs" / "3.h5"
    with pytest.raises(PipelineError) as info:
        jobserver.run_job({"stage": "solve", "log": str(tmp_path / "solve.log"),
                           "args": {"forward_model": ANALYTIC, "point": {"E": 400.0, "nu": 0.3},
                                    "out": str(out), "base": str(state)}})
    _assert_set_aside(info, state, "warm-start state", cut)
    assert not out.exists()


def test_a_truncated_vtu_field_file_is_set_aside_by_the_field_figure(tmp_path):
    vtu = tmp_path / "observations" / "ground_truth.vtu"
    vtu.parent.mkdir()
    vtu.write_text('<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0">\n'
                   '  <UnstructuredGrid>\n    <Piece NumberOfPoints="3" NumberOfCells="1">\n'
                   '      <Points>\n')
    run = tmp_path / "observations" / "ground_truth_run.h5"
    solve_point(ANALYTIC, {"E": 400.0, "nu": 0.3}, run, isolate=False)
    with pytest.raises(PipelineError) as info:
        figures.field_figure(vtu, run, PLOTS, tmp_path / "fig" / "fields")
    _assert_set_aside(info, vtu, "VTU field file", Path(f"{vtu}.corrupt").read_bytes())


@pytest.mark.parametrize("kind", ["training table", "surrogate"])
def test_a_truncated_hdf5_stage_output_is_set_aside_by_the_response_figure(tmp_path, kind):
    """The figure stages read the training table and the surrogate through the same
    reader as the inference stages."""
    from bayescalib.inference.gp import fit_gp
    from bayescalib.io.training import write_training

    X = np.column_stack([np.linspace(150, 750, 8), np.linspace(-0.7, 0.4, 8)])
    L = -((X[:, 0] - 400) / 300) ** 2 - ((X[:, 1] - 0.3) / 0.5) ** 2
    training, surrogate = tmp_path / "rkhs" / "training.h5", tmp_path / "rkhs" / "surrogate.h5"
    write_training(training, X, L, L, np.ones(8, bool), [""] * 8, ["E", "nu"], 8,
                   bound=np.zeros(8))
    fit_gp(X, L, bounds=np.array([[100.0, 800.0], [-0.8, 0.45]]), bound=0.0,
           restarts=1,
           kernel="matern32", nugget="fixed", mean="constant", ard=False, warp=True).save(surrogate)
    path = training if kind == "training table" else surrogate
    cut = _truncate(path)
    with pytest.raises(PipelineError) as info:
        figures.response_figures(training, surrogate, PARAMETERS, PLOTS, tmp_path / "fig" / "r")
    _assert_set_aside(info, path, kind, cut)


def test_truncated_run_records_and_observations_are_set_aside_by_the_interface_figure(
        tmp_path):
    truth = tmp_path / "observations" / "ground_truth_run.h5"
    solve_point(ANALYTIC, {"E": 400.0, "nu": 0.3}, truth, isolate=False)
    obs = tmp_path / "observations" / "observations.h5"
    observe({"source": "synthetic", "noise_sigma": 0.0, "seed": 0}, obs,
            ground_truth_run=truth)
    sample = tmp_path / "runs" / "posterior_sample_0.h5"
    solve_point(ANALYTIC, {"E": 420.0, "nu": 0.3}, sample, isolate=False)
    cut = _truncate(sample)
    with pytest.raises(PipelineError) as info:
        figures.interface_figure(obs, [sample], PLOTS, tmp_path / "fig" / "interfaces")
    _assert_set_aside(info, sample, "run record", cut)
    cut = _truncate(obs)
    with pytest.raises(PipelineError) as info:
        figures.interface_figure(obs, [], PLOTS, tmp_path / "fig" / "interfaces")
    _assert_set_aside(info, obs, "observation set", cut)


def test_an_unknown_kind_is_a_programming_error_naming_the_kinds(tmp_path):
    with pytest.raises(ValueError, match="unknown kind of stage file 'posterior'.*posterior "
                                         "summary"):
        read_stage_file(tmp_path / "x.json", "posterior")


def test_a_truncated_previous_round_surrogate_is_set_aside_not_called_unfittable(tmp_path):
    """An active round's fit reads the previous round's surrogate: a damaged one is set
    aside (before, it was reported as a GP that cannot be fitted, on every rerun)."""
    from bayescalib.config import validate
    from bayescalib.inference.gp import fit_gp
    from bayescalib.io.training import write_training

    X = np.column_stack([np.linspace(150, 750, 8), np.linspace(-0.7, 0.4, 8)])
    L = -((X[:, 0] - 400) / 300) ** 2 - ((X[:, 1] - 0.3) / 0.5) ** 2
    training = tmp_path / "active" / "1" / "training.h5"
    write_training(training, X, L, L, np.ones(8, bool), [""] * 8, ["E", "nu"], 8,
                   bound=np.zeros(8))
    previous = tmp_path / "active" / "0" / "surrogate.h5"
    fit_gp(X, L, bounds=np.array([[100.0, 800.0], [-0.8, 0.45]]), bound=0.0,
           restarts=1,
           kernel="matern32", nugget="fixed", mean="constant", ard=False, warp=True).save(previous)
    cut = _truncate(previous)
    surrogate = validate({"surrogate": {"restarts": 1}}, "inference")["surrogate"]
    with pytest.raises(PipelineError) as info:
        train_surrogate(training, surrogate, PARAMETERS,
                        tmp_path / "active" / "1" / "surrogate.h5", previous=previous)
    _assert_set_aside(info, previous, "surrogate", cut)
