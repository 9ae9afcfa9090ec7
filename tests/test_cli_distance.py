"""Tests of ``bayescalib distance``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from _interface_shapes import circle

from bayescalib.cli import main
from bayescalib.measures import compute
from bayescalib.observations import write_interface_csv, write_interface_vtk


@pytest.fixture
def files(tmp_path):
    model, obs = circle(0.4, 60), circle(0.41, 400)
    write_interface_csv(tmp_path / "model.csv", model)
    write_interface_vtk(tmp_path / "obs.vtp", obs)
    return tmp_path, model, obs


def test_distance_cpp_json(files, capsys):
    d, model, obs = files
    assert main(["distance", "--measure", "cpp", "--json", str(d / "model.csv"), str(d / "obs.vtp")]) == 0
    out = json.loads(capsys.readouterr().out)
    ref = compute("cpp", model, obs)
    assert out["n"] == 60 and out["D"] == pytest.approx(ref.D, rel=1e-12)
    np.testing.assert_allclose(out["distances"], ref.distances, rtol=1e-12)


def test_distance_rkhs_plain_and_units(files, capsys):
    d, model, obs = files
    assert main(["distance", "--sigma-w", "0.01", str(d / "model.csv"), str(d / "obs.vtp")]) == 0
    val = float(capsys.readouterr().out)
    assert val == pytest.approx(compute("rkhs", model, obs, sigma_w=0.01).D, rel=1e-10)
    # both files read as um: coordinates / 1000, so the CPP distance scales by 1/1000
    assert main(["distance", "--measure", "cpp", "--units", "um", str(d / "model.csv"), str(d / "obs.vtp")]) == 0
    assert float(capsys.readouterr().out) == pytest.approx(compute("cpp", model, obs).D / 1000, rel=1e-9)
    # read as metres, the 0.4 m circle is far too large for sigma_W = 0.005 mm: clear error
    assert main(["distance", "--units", "m", str(d / "model.csv"), str(d / "obs.vtp")]) == 2
    assert "check the units" in capsys.readouterr().err


def test_distance_euclidean_points_file(files, capsys):
    d, _model, _obs = files
    (d / "pts.csv").write_text("x,y\n0.41,0\n0,0.41\n")
    assert main(["distance", "--measure", "euclidean", "--points", str(d / "pts.csv"), "--json",
                 str(d / "model.csv"), str(d / "obs.vtp")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n"] == 2
    # radial directions from the observed normal; the 60-gon's chord sits inside r = 0.4
    np.testing.assert_allclose(out["distances"], -0.01, atol=0.4 * (1 - math.cos(math.pi / 60)) + 1e-6)


def test_distance_bad_input_exits_2(files, capsys):
    d, _, _ = files
    (d / "bad.csv").write_text("x,y\n0,0\n")
    assert main(["distance", str(d / "bad.csv"), str(d / "obs.vtp")]) == 2
    err = capsys.readouterr().err
    assert "bad.csv" in err and "single point" in err and len(err.strip().splitlines()) == 1
    assert main(["distance", str(d / "missing.csv"), str(d / "obs.vtp")]) == 2
    assert "missing.csv" in capsys.readouterr().err
