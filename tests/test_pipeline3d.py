"""The pipeline's stages on 3D interfaces (issue 40 item 3): synthetic observations made
from a 3D run record, the discrepancy of a 3D run against them, the interfaces figure
(mid-plane sections), and the study's refusal of observations whose dimension is not
the model's, before any solve. Run records here are made up (a dome over a rectangle),
not solved: the stages read surfaces the way they read curves."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bayescalib.config import ConfigError, deep_merge, load_yaml, validate
from bayescalib.geometry.interface import Interface
from bayescalib.io.observation_store import read_observations
from bayescalib.io.observations import write_interface_csv, write_interface_vtk
from bayescalib.io.runrecord import LoadingResult, SolveResult, write_run
from bayescalib.stages.discrepancy import discrepancy
from bayescalib.stages.errors import PipelineError
from bayescalib.stages.figures import interface_figure
from bayescalib.stages.observe import observe
from bayescalib.study import Study

ROOT = Path(__file__).resolve().parents[1]
MEASURE = {"sigma_w": 0.1}  # the options of measure.rkhs
LIK = {"sigma_n2": 2.0e-6}


def _dome(n: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """A dome y = 0.4 (1 - r^2) over [0.7, 1.3] x [0.2, 0.8] (x, z), triangulated."""
    x, z = np.meshgrid(np.linspace(0.7, 1.3, n), np.linspace(0.2, 0.8, n), indexing="ij")
    r2 = np.clip(((x - 1.0) / 0.3) ** 2 + ((z - 0.5) / 0.3) ** 2, 0.0, 1.0)
    pts = np.column_stack([x.ravel(), (0.4 * (1.0 - r2)).ravel(), z.ravel()])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.vstack([np.column_stack([a, c, b]), np.column_stack([a, d, c])])
    return pts, tri


def _bent(pts: np.ndarray, shift: float) -> np.ndarray:
    """The dome pushed downstream in proportion to height."""
    out = pts.copy()
    out[:, 0] += shift * pts[:, 1] / 0.4
    return out


def _run(path: Path, shift: float, factors=(0.5, 1.0)) -> Path:
    ref, tri = _dome()
    loads = [LoadingResult(label=f"f{f:g}", factor=f, value=100.0 * f,
                           current=_bent(ref, shift * f)) for f in factors]
    write_run(path, SolveResult(
        status="ok", reason="", parameters={"material.E": 400.0, "material.nu": 0.3},
        load_fraction=1.0, newton_iterations=3, load_steps=1, wall_time=1.0,
        interface_reference=ref, interface_current=loads[-1].current, segments=tri,
        max_displacement=shift, stats={"dim": 3}, loadings=loads))
    return path


def _observations(section):
    return validate({"observations": section}, "measures")["observations"]


@pytest.fixture()
def synthetic3d(tmp_path):
    _run(tmp_path / "truth.h5", 0.02)
    observe(_observations({"source": "synthetic", "noise_sigma": 0.001, "seed": 3}),
            tmp_path / "obs.h5", ground_truth_run=tmp_path / "truth.h5")
    return tmp_path


def test_synthetic_observations_of_a_3d_run_are_its_surfaces_with_noise(synthetic3d):
    obs = read_observations(synthetic3d / "obs.h5")
    ref, tri = _dome()
    assert obs.labels == ["f0.5", "f1"] and obs.loads == pytest.approx([50.0, 100.0])
    assert obs.reference.dim == 3
    np.testing.assert_array_equal(obs.reference.points, ref)
    for snap, f in zip(obs.snapshots, (0.5, 1.0)):
        assert snap.dim == 3
        np.testing.assert_array_equal(snap.cells, tri)
        noise = snap.points - _bent(ref, 0.02 * f)
        assert 0.0007 < noise.std() < 0.0013 and abs(noise.mean()) < 3e-4


def test_the_discrepancy_of_a_3d_run_sums_over_snapshots_and_grows_with_the_misfit(synthetic3d):
    tmp = synthetic3d
    near = discrepancy(_run(tmp / "0.h5", 0.02), tmp / "obs.h5", "rkhs", MEASURE, LIK,
                       tmp / "d0.json")
    far = discrepancy(_run(tmp / "1.h5", 0.03), tmp / "obs.h5", "rkhs", MEASURE, LIK,
                      tmp / "d1.json")
    assert near["status"] == far["status"] == "ok"
    assert [s["label"] for s in far["snapshots"]] == ["f0.5", "f1"]
    assert far["loglik"] == pytest.approx(sum(s["loglik"] for s in far["snapshots"]))
    # at the truth only the noise is left; 10 um more bending at the top is far more
    assert 0.0 < near["D"] < 0.5 * far["D"]
    assert far["snapshots"][0]["D"] < far["snapshots"][1]["D"]
    assert near["loglik"] > far["loglik"]


def test_a_3d_run_against_a_2d_observation_set_is_refused_naming_both(tmp_path):
    from bayescalib.io.observation_store import StoredObservations, write_observations

    curve = Interface.polyline(np.column_stack([np.linspace(0.7, 1.3, 20),
                                                np.sin(np.linspace(0, np.pi, 20)) * 0.4]))
    write_observations(tmp_path / "obs.h5", StoredObservations([curve, curve], ["f0.5", "f1"],
                                                               [50.0, 100.0]))
    with pytest.raises(PipelineError, match="is a 2D curve but the model's .* is a 3D surface"):
        discrepancy(_run(tmp_path / "0.h5", 0.02), tmp_path / "obs.h5", "rkhs", MEASURE, LIK,
                    tmp_path / "d.json")


def test_the_interfaces_figure_shows_mid_plane_sections_of_3d_surfaces(synthetic3d, tmp_path):
    paths = interface_figure(synthetic3d / "obs.h5", [_run(tmp_path / "s.h5", 0.025)],
                             {"formats": ["png"], "dpi": 40}, tmp_path / "interfaces",
                             ground_truth_run=synthetic3d / "truth.h5")
    assert [Path(p).name for p in paths] == ["interfaces.png"]
    assert Path(paths[0]).stat().st_size > 0


def test_bayescalib_distance_compares_a_3d_run_record_with_a_surface_file(tmp_path, capsys):
    from bayescalib.cli import main
    from bayescalib.measures import compute

    ref, tri = _dome()
    obs = Interface.surface(_bent(ref, 0.03), tri)
    write_interface_vtk(tmp_path / "obs.vtp", obs)
    _run(tmp_path / "run.h5", 0.02)
    assert main(["distance", "--sigma-w", "0.1", str(tmp_path / "run.h5"),
                 str(tmp_path / "obs.vtp")]) == 0
    want = compute("rkhs", Interface.surface(_bent(ref, 0.02), tri), obs, sigma_w=0.1).D
    assert float(capsys.readouterr().out) == pytest.approx(want, rel=1e-9)


# ------------------------------------------------------------------ the study's checks
DEFAULT = load_yaml(ROOT / "config" / "config.yaml")
#: the 3D smoke study as the workflow reads it: layered on the default study
FSI3D = deep_merge(DEFAULT, load_yaml(ROOT / "config" / "fsi3d_smoke.yaml"))


def test_the_3d_smoke_study_reads_as_a_3d_study():
    study = Study(FSI3D)
    assert study.interface_dim == 3 and Study(DEFAULT).interface_dim == 2


def test_a_2d_observation_file_for_the_3d_model_is_refused_before_any_solve(tmp_path):
    curve = Interface.polyline(np.column_stack([np.linspace(0.7, 1.3, 20),
                                                0.4 * np.sin(np.linspace(0, np.pi, 20))]))
    write_interface_csv(tmp_path / "obs.csv", curve)
    cfg = deep_merge(FSI3D, {"observations": {"source": "files", "files": [
        {"path": str(tmp_path / "obs.csv"), "load": 50.0},
        {"path": str(tmp_path / "obs.csv"), "load": 100.0}]}})
    with pytest.raises(ConfigError, match=r"observations.files\[0\] .* is a 2D curve, but the "
                       r"model's interface is a 3D surface \(forward_model.fsi.geometry.dim: 3\)"):
        Study(cfg)


def test_a_3d_surface_file_for_the_2d_model_is_refused_before_any_solve(tmp_path):
    ref, tri = _dome()
    write_interface_vtk(tmp_path / "obs.vtp", Interface.surface(ref, tri))
    cfg = deep_merge(DEFAULT, {"observations": {"source": "files", "files": [
        {"path": str(tmp_path / "obs.vtp")}]}})
    with pytest.raises(ConfigError, match=r"is a 3D surface, but the model's interface is a "
                       r"2D curve"):
        Study(cfg)


def test_misregistration_is_refused_for_the_3d_model():
    cfg = deep_merge(FSI3D, {"observations": {"misregistration": {"shift_x": 0.01}}})
    with pytest.raises(ConfigError, match="misregistration is a 2D misplacement"):
        Study(cfg)


def test_the_diagnosis_is_accepted_for_the_3d_model_with_its_candidate_library():
    """The diagnosis reads observed surfaces (residuals on their nodes) and the 3D model
    has the candidate physics: a 3D study with the diagnosis is read, and its library is
    the whole of the 3D model's."""
    from bayescalib.diagnosis.stage import resolve_candidates
    from bayescalib.models.fsi.model import PHYSICS_3D

    study = Study(deep_merge(FSI3D, {"diagnose": {"enabled": True}}))
    fm = study.forward_section()
    names = [c.name for c in resolve_candidates(fm, study.config["diagnose"])]
    assert names == list(PHYSICS_3D)


# extended suite (pytest -m extended, run by .ci/run): the 3D smoke study end to end on
# the 3D model's very coarse mesh (about 4 minutes on 2 cores)
@pytest.mark.extended
def test_the_3d_smoke_study_runs_end_to_end(tmp_path):
    import json

    from _workflow_helpers import setup_study, smk

    smk(setup_study(tmp_path, FSI3D), timeout=1800)
    root = tmp_path / "results" / "fsi3d_smoke"
    s = json.loads((root / "summary.json").read_text())
    assert s["ground_truth"] == {"E": 400.0, "nu": 0.3}
    assert 8 <= s["design"]["n_solves"] <= 48 and s["n_failed"] == 0
    # the figures in 3D: the interfaces and the fields as mid-plane sections
    assert "interfaces" in s["figures"] and "fields" in s["figures"]
    assert (root / "figures" / "interfaces.png").is_file()
    assert (root / "figures" / "fields.png").is_file()
    assert (root / "observations" / "ground_truth.vtu").is_file()
    obs = read_observations(root / "observations" / "observations.h5")
    assert [x.dim for x in obs.snapshots] == [3, 3] and obs.loads == pytest.approx([50.0, 100.0])
    mean, sd = s["posterior_mean"], s["posterior_sd"]
    # E is what two flow rates measure: within 3 posterior sd of the truth, and the
    # posterior narrower than the prior (sd 202 Pa); nu within 3 sd (weakly identified)
    assert sd["E"] < 150.0
    if s["converged"]:
        assert abs(mean["E"] - 400.0) < 3.0 * sd["E"]
        assert abs(mean["nu"] - 0.3) < 3.0 * sd["nu"]


def test_the_3d_interfaces_figure_renders_the_observed_surface_coloured_by_the_misfit(tmp_path):
    """The rendered panel: a 3D axes beside the section, its colour bar the observed
    surface's signed distance from the model's surface, in um, symmetric about 0."""
    from bayescalib.plotting import plot_interfaces

    ref, tri = _dome()
    obs = _bent(ref, 0.02)
    d = 1e3 * (obs[:, 0] - ref[:, 0])  # a made-up misfit, um
    t = np.linspace(np.pi, 0.0, 30)  # the section's curves (the panel beside them)
    arc = np.column_stack([1.0 + 0.3 * np.cos(t), 0.4 * np.sin(t)])
    _, fig = plot_interfaces(arc, [arc + [0.01, 0.0]], None, tmp_path / "f.png",
                             surface=(obs, tri, d, "distance [um]"), return_figure=True)
    axes = fig.get_axes()
    three = [ax for ax in axes if ax.name == "3d"]
    assert len(three) == 1
    bar = [ax for ax in axes if ax.get_xlabel() == "distance [um]"]
    assert len(bar) == 1 and bar[0].get_xlim() == pytest.approx((-d.max(), d.max()), rel=0.05)
