"""``bayescalib solve``: one-line JSON summary, outputs, and clear config errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bayescalib.cli import main
from bayescalib.io.runrecord import read_run


def _run(capsys, argv):
    rc = main(["solve", *argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_solve_prints_one_json_line(tmp_path, capsys):
    rc, out, err = _run(capsys, ["--set", "mesh.preset=coarse", "--set", "material.E=500",
                                 "--out", str(tmp_path), "--vtu"])
    assert rc == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 1
    summary = json.loads(lines[0])
    assert summary["status"] == "ok"
    assert summary["newton_iterations"] > 0
    assert 0.01 < summary["max_displacement_mm"] < 0.04
    assert summary["wall_time_s"] > 0
    rec = read_run(summary["output"])
    assert rec.parameters["material.E"] == 500.0
    assert (tmp_path / "run.vtu").is_file()
    # warm start from the saved state
    rc, out, _ = _run(capsys, ["--set", "mesh.preset=coarse", "--set", "material.E=520",
                               "--out", str(tmp_path / "w"), "--warm-start",
                               str(tmp_path / "run.state.npz")])
    warm = json.loads(out)
    assert rc == 0 and warm["status"] == "ok"
    assert warm["newton_iterations"] < summary["newton_iterations"]


def test_study_config_forward_model_section(tmp_path, capsys):
    cfg = tmp_path / "study.yaml"
    cfg.write_text("study: x\nforward_model:\n  fsi:\n    mesh: {preset: coarse}\n    inflow: {rate: 0.0}\n")
    rc, out, err = _run(capsys, ["--config", str(cfg), "--out", str(tmp_path / "o")])
    assert rc == 0, err
    s = json.loads(out)
    assert s["status"] == "ok" and s["max_displacement_mm"] < 1e-12


def test_failed_solve_is_recorded(tmp_path, capsys):
    rc, out, _ = _run(capsys, ["--set", "mesh.preset=coarse", "--set", "material.nu=0.5",
                               "--out", str(tmp_path)])
    s = json.loads(out)
    assert rc == 0 and s["status"] == "failed" and "nu" in s["reason"]
    assert read_run(tmp_path / "run.h5").status == "failed"


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--set", "material.EE=3"], "material.EE"),
        (["--set", "mesh.h_interface=-1"], "mesh.h_interface"),
        (["--set", "material.nu=0.7"], "material.nu"),
        (["--set", "material.law=mooney"], "material.law"),
        (["--set", "inflow"], "inflow"),
        (["--set", "inflow.rate.x=1"], "inflow.rate"),
    ],
)
def test_bad_overrides_name_the_key(tmp_path, capsys, argv, needle):
    rc, out, err = _run(capsys, [*argv, "--out", str(tmp_path)])
    assert rc == 2
    assert needle in err
    assert out == ""
    assert len(err.strip().splitlines()) == 1


def test_bad_config_file(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("mesh: [unclosed\n")
    rc, _, err = _run(capsys, ["--config", str(bad), "--out", str(tmp_path)])
    assert rc == 2 and "bad.yaml" in err
    unknown = tmp_path / "unknown.yaml"
    unknown.write_text("geometry: {widht: 0.5}\n")
    rc, _, err = _run(capsys, ["--config", str(unknown), "--out", str(tmp_path)])
    assert rc == 2 and "geometry.widht" in err and "width" in err
    rc, _, err = _run(capsys, ["--config", str(tmp_path / "missing.yaml"), "--out", str(tmp_path)])
    assert rc == 2 and "missing.yaml" in err


def test_bad_warm_start_file(tmp_path, capsys):
    rc, _, err = _run(capsys, ["--set", "mesh.preset=coarse", "--out", str(tmp_path),
                               "--warm-start", str(tmp_path / "nothing.npz")])
    assert rc == 2 and "nothing.npz" in err


def test_a_study_config_with_two_loadings_records_both(tmp_path, capsys):
    """The command solves as the workflow does (solve_points): forward_model.loadings
    of a study config are solved and recorded, one snapshot per factor."""
    cfg = tmp_path / "study.yaml"
    cfg.write_text("study: x\nforward_model:\n  fsi:\n    mesh: {preset: coarse}\n"
                   "  loadings: {factors: [0.5, 1.0]}\n")
    rc, out, err = _run(capsys, ["--config", str(cfg), "--set", "material.E=500",
                                 "--out", str(tmp_path / "o")])
    assert rc == 0, err
    s = json.loads(out)
    assert s["status"] == "ok" and s["loadings"] == ["load_0.5", "load_1"]
    rec = read_run(s["output"])
    assert [ld.factor for ld in rec.loadings] == [0.5, 1.0]
    assert [ld.value for ld in rec.loadings] == [50.0, 100.0]  # the fsi inflow rate, 100
    half, full = (ld.current - rec.interface_reference for ld in rec.loadings)
    assert 0 < np.abs(half).max() < np.abs(full).max()
    np.testing.assert_array_equal(rec.loadings[1].current, rec.interface_current)
    # a series ends in no single load: no warm-start state is written for it
    assert not (tmp_path / "o" / "run.state.npz").exists()


def test_points_file_solves_one_point_per_row(tmp_path, capsys):
    pts = tmp_path / "points.csv"
    pts.write_text("material.E,material.nu\n450,0.3\n600,0.2\n")
    rc, out, err = _run(capsys, ["--set", "mesh.preset=coarse", "--points", str(pts),
                                 "--out", str(tmp_path / "o")])
    assert rc == 0, err
    lines = [json.loads(x) for x in out.strip().splitlines()]
    assert [x["status"] for x in lines] == ["ok", "ok"]
    recs = [read_run(x["output"]) for x in lines]
    assert [(r.parameters["material.E"], r.parameters["material.nu"]) for r in recs] == \
        [(450.0, 0.3), (600.0, 0.2)]
    assert recs[0].max_displacement > recs[1].max_displacement  # softer moves more
    assert (tmp_path / "o" / "run_1.state.npz").is_file()


@pytest.mark.parametrize("text, needle", [
    ("material.EE\n3\n", "material.EE"),
    ("material.E\nabc\n", "line 2"),
    ("material.E\n", "at least one row"),
])
def test_bad_points_file_names_the_problem(tmp_path, capsys, text, needle):
    pts = tmp_path / "points.csv"
    pts.write_text(text)
    rc, out, err = _run(capsys, ["--set", "mesh.preset=coarse", "--points", str(pts),
                                 "--out", str(tmp_path / "o")])
    assert rc == 2 and needle in err and out == ""


def test_a_study_of_another_forward_model_is_refused(tmp_path, capsys):
    cfg = tmp_path / "study.yaml"
    cfg.write_text("study: x\nforward_model:\n  type: python\n"
                   "  python: {function: 'bayescalib.models.analytic:interface'}\n")
    rc, out, err = _run(capsys, ["--config", str(cfg), "--out", str(tmp_path / "o")])
    assert rc == 2 and "forward_model.type" in err and out == ""
