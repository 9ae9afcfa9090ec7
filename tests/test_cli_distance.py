"""Tests of ``bayescalib distance``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from _interface_shapes import circle, dome

from bayescalib.cli import main
from bayescalib.io.observations import write_interface_csv, write_interface_vtk
from bayescalib.measures import compute


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
    # the same curves written in um and read with --units um give the same D (in mm)
    from bayescalib.geometry.interface import Interface

    write_interface_csv(d / "model_um.csv", Interface.polyline(1000.0 * np.asarray(model.points)))
    write_interface_vtk(d / "obs_um.vtp", Interface.polyline(1000.0 * np.asarray(obs.points)))
    assert main(["distance", "--measure", "cpp", "--units", "um", str(d / "model_um.csv"),
                 str(d / "obs_um.vtp")]) == 0
    assert float(capsys.readouterr().out) == pytest.approx(compute("cpp", model, obs).D, rel=1e-9)
    # read as metres, a 0.8 m wide "interface" is no flow-cell interface: a unit slip,
    # refused at once for every measure (before any work)
    for measure in ("rkhs", "cpp"):
        assert main(["distance", "--measure", measure, "--units", "m", str(d / "model.csv"),
                     str(d / "obs.vtp")]) == 2
        err = capsys.readouterr().err
        assert "not a flow-cell interface" in err and "check --units" in err


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


def test_distance_reads_the_run_record_a_solve_writes(tmp_path, capsys):
    """``bayescalib solve`` and the workflow write run records (.h5): their deformed
    interface is compared as is (mm); the field file of a solve is refused with advice."""
    from bayescalib.geometry.interface import Interface
    from bayescalib.models.forward import solve_point

    fm = {"type": "python", "python": {"function": "bayescalib.models.analytic:interface"}}
    res = solve_point(fm, {"E": 400.0, "nu": 0.3}, tmp_path / "run.h5", isolate=False)
    obs = Interface.polyline(np.asarray(res.interface_current) + [0.0, 0.002])
    write_interface_csv(tmp_path / "obs.csv", obs)
    assert main(["distance", "--measure", "cpp", str(tmp_path / "run.h5"),
                 str(tmp_path / "obs.csv")]) == 0
    got = float(capsys.readouterr().out)
    ref = compute("cpp", Interface.polyline(res.interface_current, res.segments), obs).D
    assert got == pytest.approx(ref, rel=1e-12) and got > 0
    write_interface_vtk(tmp_path / "surface.vtp", dome(0.4, 1))
    assert main(["distance", str(tmp_path / "run.h5"), str(tmp_path / "surface.vtp")]) == 2
    assert "not the field file .vtu" in capsys.readouterr().err
