"""Every HDF5 file the pipeline writes, through one set of checks (one test per
property, run over all formats): it reads back what was written, carries the header
of its kind (bayescalib.io.header), and a reader refuses a file of another kind or of
another layout version, naming the file. Observation sets, training tables and
particle files of earlier runs had no header; they still read."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from bayescalib.geometry.interface import Interface
from bayescalib.inference.gp import GPSurrogate, fit_gp
from bayescalib.inference.parameters import ParameterSpace
from bayescalib.inference.posterior import read_particles_h5, write_particles_h5
from bayescalib.inference.smc import SMCResult
from bayescalib.io.header import FORMATS
from bayescalib.io.observation_store import (
    StoredObservations,
    read_observations,
    write_observations,
)
from bayescalib.io.runrecord import SolveResult, read_run, write_run
from bayescalib.io.training import read_training, write_training

RNG = np.random.default_rng(3)
X = RNG.random((12, 2))
L = -np.sum((X - 0.4) ** 2, axis=1) * 50.0


def _space():
    return ParameterSpace.from_config([
        {"name": "E", "unit": "Pa", "prior": {"type": "uniform", "lo": 0.0, "hi": 1.0},
         "bounds": [0.0, 1.0]},
        {"name": "nu", "prior": {"type": "uniform", "lo": 0.0, "hi": 1.0}, "bounds": [0.0, 1.0]}])


def _run(path):
    ref = np.column_stack([np.linspace(0.7, 1.3, 9), RNG.random(9)])
    write_run(path, SolveResult(
        status="ok", reason="", parameters={"material.E": 400.0}, load_fraction=1.0,
        newton_iterations=5, load_steps=1, wall_time=0.5, interface_reference=ref,
        interface_current=ref + 0.01, segments=np.column_stack([np.arange(8), np.arange(1, 9)]),
        max_displacement=0.01))
    return read_run(path).interface_current


def _observations(path):
    pts = np.column_stack([np.linspace(0.0, 1.0, 7), np.linspace(0.0, 0.2, 7)])
    write_observations(path, StoredObservations([Interface.polyline(pts)], ["scan"], [None],
                                                None, {"source": "files"}))
    return read_observations(path).snapshots[0].points


def _training(path):
    write_training(path, X, L, L * 0.1, np.ones(len(L), bool), [""] * len(L), ["E", "nu"], 10,
                   bound=np.zeros(len(L)))
    return read_training(path)["loglik"]


def _surrogate(path):
    gp = fit_gp(X, L, bounds=np.array([[0.0, 1.0]] * 2), bound=0.0, restarts=1,
                warp=True, kernel="matern32", nugget="fixed", mean="constant", ard=False)
    gp.save(path)
    return GPSurrogate.load(path).predict(X[:3])


def _particles(path):
    res = SMCResult(particles=X, weights=np.full(len(X), 1 / len(X)), loglik=L,
                    logprior=np.zeros(len(X)), log_evidence=-3.0,
                    history={"beta": np.array([0.0, 1.0])}, n_steps=1)
    write_particles_h5(path, res, _space())
    return read_particles_h5(path).particles


WRITE_READ = {"run": (_run, read_run), "observations": (_observations, read_observations),
              "training": (_training, read_training),
              "surrogate": (_surrogate, GPSurrogate.load),
              "particles": (_particles, read_particles_h5)}
EXPECTED = {"run": lambda: None, "observations": lambda: None, "training": lambda: L,
            "surrogate": lambda: None, "particles": lambda: X}


@pytest.fixture(params=sorted(WRITE_READ))
def written(request, tmp_path):
    kind = request.param
    path = tmp_path / f"{kind}.h5"
    value = WRITE_READ[kind][0](path)
    return kind, path, value


def test_what_is_written_reads_back(written):
    kind, _path, value = written
    expected = EXPECTED[kind]()
    assert value is not None and np.all(np.isfinite(np.asarray(value, float)))
    if expected is not None:
        np.testing.assert_array_equal(value, expected)
    if kind == "surrogate":  # the GP reproduces its own training values
        np.testing.assert_allclose(value, L[:3], atol=0.5)


def test_every_file_carries_the_header_of_its_kind(written):
    kind, path, _ = written
    with h5py.File(path, "r") as f:
        name, version, _ = FORMATS[kind]
        assert f.attrs["format"] == name and int(f.attrs["format_version"]) == version


def test_a_file_of_another_kind_is_refused_naming_it(written, tmp_path):
    kind, path, _ = written
    other = "particles" if kind != "particles" else "training"
    _, reader = WRITE_READ[other]
    with pytest.raises(ValueError, match=f"{path.name}.*not a bayescalib"):
        reader(path)


def test_a_file_of_another_layout_version_is_refused_naming_it(written):
    kind, path, _ = written
    with h5py.File(path, "a") as f:
        f.attrs["format_version"] = FORMATS[kind][1] + 1
    with pytest.raises(ValueError, match=f"{path.name}.*version"):
        WRITE_READ[kind][1](path)


@pytest.mark.parametrize("kind", ["observations", "training", "particles"])
def test_files_from_before_the_header_still_read(kind, tmp_path):
    path = tmp_path / f"{kind}.h5"
    WRITE_READ[kind][0](path)
    with h5py.File(path, "a") as f:
        del f.attrs["format"]
        del f.attrs["format_version"]
    WRITE_READ[kind][1](path)
