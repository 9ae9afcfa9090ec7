"""A stage of the primary measure reuses the last active round's output when its input
is the same (bayescalib.stages.surrogate.train_surrogate and bayescalib.stages.smc.smc
with ``reuse``): the copy is bitwise what the stage would compute; a different input is
computed anew."""

from __future__ import annotations

import numpy as np

from bayescalib.config import validate
from bayescalib.io.training import write_training
from bayescalib.stages.files import _same_h5_content
from bayescalib.stages.smc import smc
from bayescalib.stages.surrogate import train_surrogate

PARAMETERS = [
    {"name": "E", "unit": "Pa", "target": "E", "bounds": [100.0, 800.0],
     "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0}},
    {"name": "nu", "unit": "-", "target": "nu", "bounds": [-0.8, 0.45],
     "prior": {"type": "uniform", "lo": -0.8, "hi": 0.45}},
]
SURROGATE = validate({"surrogate": {"restarts": 1}}, "inference")["surrogate"]
SMC = {**validate({}, "inference")["smc"], "n_particles": 400, "n_rej": 3, "zeta": 0.9}


def _table(path, shift: float = 0.0):
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(100, 800, 16), rng.uniform(-0.8, 0.45, 16)])
    L = -0.5 * (((X[:, 0] - 400) / 150) ** 2 + ((X[:, 1] - 0.2) / 0.3) ** 2) + shift
    write_training(path, X, L, np.sqrt(-L + 1.0), np.ones(16, bool), [""] * 16, ["E", "nu"], 16,
                   bound=np.full(16, 1.0))
    return path


def _particles(path):
    from bayescalib.inference.posterior import read_particles_h5

    res = read_particles_h5(path)
    return res.particles, res.weights, res.loglik


def test_the_measure_reuses_the_rounds_surrogate_and_particles_for_the_same_input(tmp_path):
    rnd, meas = tmp_path / "round", tmp_path / "measure"
    rnd.mkdir()
    meas.mkdir()
    train_surrogate(_table(rnd / "training.h5"), SURROGATE, PARAMETERS, rnd / "surrogate.h5")
    smc(rnd / "surrogate.h5", SMC, PARAMETERS, rnd / "particles.h5")
    # the measure's table: written anew with the same content (its file's bytes may differ)
    train_surrogate(_table(meas / "training.h5"), SURROGATE, PARAMETERS,
                    meas / "surrogate.h5",
                    reuse=[rnd / "training.h5", rnd / "surrogate.h5"])
    assert (meas / "surrogate.h5").read_bytes() == (rnd / "surrogate.h5").read_bytes()
    smc(meas / "surrogate.h5", SMC, PARAMETERS, meas / "particles.h5",
        reuse=[rnd / "surrogate.h5", rnd / "particles.h5"])
    assert (meas / "particles.h5").read_bytes() == (rnd / "particles.h5").read_bytes()
    # what the stages compute without reuse is the same, bit for bit (apart from timings)
    train_surrogate(meas / "training.h5", SURROGATE, PARAMETERS, tmp_path / "s.h5")
    assert _same_h5_content(tmp_path / "s.h5", rnd / "surrogate.h5")
    smc(tmp_path / "s.h5", SMC, PARAMETERS, tmp_path / "p.h5")
    for a, b in zip(_particles(tmp_path / "p.h5"), _particles(rnd / "particles.h5"), strict=True):
        assert np.array_equal(a, b)


def test_a_different_input_is_computed_anew(tmp_path):
    rnd, meas = tmp_path / "round", tmp_path / "measure"
    rnd.mkdir()
    meas.mkdir()
    train_surrogate(_table(rnd / "training.h5"), SURROGATE, PARAMETERS, rnd / "surrogate.h5")
    train_surrogate(_table(meas / "training.h5", shift=-1e-9), SURROGATE, PARAMETERS,
                    meas / "surrogate.h5",
                    reuse=[rnd / "training.h5", rnd / "surrogate.h5"])
    assert not _same_h5_content(meas / "training.h5", rnd / "training.h5")
    assert not _same_h5_content(meas / "surrogate.h5", rnd / "surrogate.h5")
    smc(rnd / "surrogate.h5", SMC, PARAMETERS, rnd / "particles.h5")
    smc(meas / "surrogate.h5", SMC, PARAMETERS, meas / "particles.h5",
        reuse=[rnd / "surrogate.h5", rnd / "particles.h5"])
    assert not np.array_equal(_particles(meas / "particles.h5")[2],
                              _particles(rnd / "particles.h5")[2])


def test_an_unreadable_earlier_output_is_not_copied(tmp_path):
    """The same input, but the round's surrogate file is damaged: the measure's surrogate
    is fitted anew (and is the one the round should have had), not copied."""
    rnd, meas = tmp_path / "round", tmp_path / "measure"
    rnd.mkdir()
    meas.mkdir()
    train_surrogate(_table(rnd / "training.h5"), SURROGATE, PARAMETERS, rnd / "surrogate.h5")
    good = rnd / "good.h5"
    good.write_bytes((rnd / "surrogate.h5").read_bytes())
    (rnd / "surrogate.h5").write_bytes((rnd / "surrogate.h5").read_bytes()[:200])
    train_surrogate(_table(meas / "training.h5"), SURROGATE, PARAMETERS,
                    meas / "surrogate.h5",
                    reuse=[rnd / "training.h5", rnd / "surrogate.h5"])
    assert _same_h5_content(meas / "surrogate.h5", good)
