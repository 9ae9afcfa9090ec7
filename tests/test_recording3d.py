"""Synthetic OCT volumes of a 3D colony (bayescalib.geometry.recording3d) read back the
way a study reads them, and the comparison of a 3D model above the plane its observed
surface was cut at (an OCT volume's floor lies on the bright substrate's halo).

The colony is the 3D smoke study's half-ellipsoid (semi-axes 0.3 x 0.4 x 0.3 mm)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bayescalib.config import deep_merge, load_yaml, validate
from bayescalib.geometry.interface import Interface
from bayescalib.geometry.projection import closest_points
from bayescalib.geometry.recording import ScanSettings
from bayescalib.geometry.recording3d import height_field, render_volume, volume_grid
from bayescalib.geometry.volume import volume_surface
from bayescalib.io.observation_store import StoredObservations, read_observations
from bayescalib.io.runrecord import LoadingResult, SolveResult
from bayescalib.io.volumes import write_volume_recording
from bayescalib.measures import rkhs
from bayescalib.models.fsi.geometry3d import reference_surface
from bayescalib.stages.discrepancy import model_interfaces
from bayescalib.stages.observe import observe

ROOT = Path(__file__).resolve().parents[1]
GEOMETRY = validate(deep_merge(load_yaml(ROOT / "config" / "config.yaml"),
                               load_yaml(ROOT / "config" / "fsi3d_smoke.yaml"))
                    ["forward_model"]["fsi"], "fsi")["geometry"]
PIXEL, SLICE = 0.01, 0.012  # mm: B-scan pixels, B-scan spacing
SETTINGS = ScanSettings(pixel_size=PIXEL, margin=0.05, substrate_thickness=3 * PIXEL,
                        below_substrate=2 * PIXEL, supersample=4)


@pytest.fixture(scope="module")
def colony():
    return reference_surface(GEOMETRY, n=32)


@pytest.fixture(scope="module")
def recorded(colony, tmp_path_factory):
    """The colony at rest written as a recording, and its volume read back."""
    out = tmp_path_factory.mktemp("rec")
    rec = write_volume_recording(out, [colony], [0.0], nominal=100.0, settings=SETTINGS,
                                 slice_spacing=SLICE, seed=3)
    return out, rec


def test_the_height_field_of_a_half_ellipsoid_is_its_analytic_top(colony):
    x = np.linspace(0.75, 1.25, 21)
    z = np.linspace(0.25, 0.75, 17)
    h = height_field(colony, x, z)
    X, Z = np.meshgrid(x, z)
    r2 = ((X - 1.0) / 0.3) ** 2 + ((Z - 0.5) / 0.3) ** 2
    inside = r2 < 0.95
    exact = 0.4 * np.sqrt(1.0 - r2[inside])
    # the surface is flat triangles through points of the ellipsoid: below it by at most
    # the chord's sag, a few um at 32 rings (steepest near the rim)
    assert np.all(h[inside] <= exact + 1e-9)
    assert np.max(exact - h[inside]) < 0.01
    assert np.isnan(height_field(colony, np.array([0.2]), np.array([0.5]))).all()  # outside


def test_a_rendered_volume_reads_back_within_a_voxel_above_the_halo(colony, recorded):
    _, rec = recorded
    assert rec["voxel_size"] == pytest.approx([10.0, 10.0, 12.0])  # um
    shape, origin = volume_grid(np.array([colony.points.min(0), colony.points.max(0)]),
                                SETTINGS, SLICE)
    assert rec["volume_shape"] == list(shape)
    assert rec["origin"] == pytest.approx([1e3 * v for v in origin])
    img = render_volume(colony, shape=shape, origin=origin, slice_spacing=SLICE,
                        settings=SETTINGS, rng=np.random.default_rng(3))
    surf, info = volume_surface(img, voxel_size=(PIXEL, PIXEL, SLICE), units="mm",
                                origin=origin, floor="auto")
    assert info["kind"] == "scan" and info["floor"]["method"] == "bright band"
    # the substrate's own edge is the floor y = 0 within a voxel; the cut lies on the
    # halo above it, within two voxels (the 2D rule of geometry.imaging.find_floor)
    assert abs(info["floor"]["edge_y_mm"]) <= PIXEL + 1e-12
    assert 0.0 < info["floor"]["y_mm"] <= 2 * PIXEL + 1e-12
    d = np.abs(closest_points(surf.points, colony)[0])
    above = surf.points[:, 1] > 3 * PIXEL  # the foot: widened by the halo's blur
    assert d[above].mean() < 0.2 * PIXEL and np.quantile(d[above], 0.99) < PIXEL


def test_a_3d_model_is_compared_above_the_cut_of_its_observed_surface(colony, recorded,
                                                                      tmp_path):
    out, rec = recorded
    entry = {"path": str(out / "volume_0.tif"), "units": "um", "pixel_size": rec["voxel_size"],
             "origin": rec["origin"], "floor": "auto"}
    section = validate({"observations": {"source": "files", "files": [entry]}},
                       "measures")["observations"]
    observe(section, tmp_path / "obs.h5")
    obs = read_observations(tmp_path / "obs.h5")
    (cut,) = obs.cut_heights()  # kept in observations.h5 with the volume's record
    assert obs.segmentation[0]["kind"] == "volume" and 0.0 < cut <= 2 * PIXEL + 1e-12
    run = SolveResult(status="ok", reason="", parameters={}, load_fraction=1.0,
                      newton_iterations=1, load_steps=1, wall_time=0.0,
                      interface_reference=colony.points, interface_current=colony.points,
                      segments=colony.cells, max_displacement=0.0, stats={"dim": 3},
                      loadings=[LoadingResult("f0", 0.0, 0.0, colony.points)])
    (whole,) = model_interfaces(run, 1)
    (above,) = model_interfaces(run, 1, obs.cut_heights())
    assert whole.points.min(axis=0)[1] == pytest.approx(0.0, abs=1e-12)
    assert above.points.min(axis=0)[1] == pytest.approx(cut, abs=1e-9)
    seen = obs.snapshots[0]
    # the colony's foot below the cut, absent from the data, is most of the misfit
    assert rkhs(above, seen, sigma_w=0.1).D < 0.5 * rkhs(whole, seen, sigma_w=0.1).D
    # a 2D or synthetic observation set has no cut: every model compared whole
    synthetic = StoredObservations([seen], ["s"], [None])
    assert synthetic.cut_heights() == [None]
    assert model_interfaces(run, 1, synthetic.cut_heights())[0].n_points == whole.n_points


def test_write_volume_recording_needs_one_surface_per_factor(colony, tmp_path):
    with pytest.raises(ValueError, match="one surface per loading factor"):
        write_volume_recording(tmp_path, [colony], [0.5, 1.0], nominal=100.0,
                               settings=SETTINGS, slice_spacing=SLICE, seed=0)
    with pytest.raises(ValueError, match="needs a 3D surface"):
        height_field(Interface.polyline(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0]])),
                     np.zeros(1), np.zeros(1))


def test_bayescalib_distance_reads_a_volume_and_compares_above_its_cut(colony, recorded,
                                                                        tmp_path, capsys):
    from bayescalib.cli import main
    from bayescalib.io.observations import write_interface_vtk

    out, rec = recorded
    write_interface_vtk(tmp_path / "model.vtp", colony)
    mm = [str(v / 1e3) for v in (*rec["voxel_size"], *rec["origin"])]  # both files in mm
    assert main(["distance", "--sigma-w", "0.1", "--voxel-size", *mm[:3], "--volume-origin",
                 *mm[3:], str(tmp_path / "model.vtp"), str(out / "volume_0.tif")]) == 0
    d = float(capsys.readouterr().out)
    entry = {"path": str(out / "volume_0.tif"), "units": "um", "pixel_size": rec["voxel_size"],
             "origin": rec["origin"], "floor": "auto"}
    section = validate({"observations": {"source": "files", "files": [entry]}},
                       "measures")["observations"]
    observe(section, tmp_path / "obs.h5")
    stored = read_observations(tmp_path / "obs.h5")
    run = SolveResult(status="ok", reason="", parameters={}, load_fraction=1.0,
                      newton_iterations=1, load_steps=1, wall_time=0.0,
                      interface_reference=colony.points, interface_current=colony.points,
                      segments=colony.cells, max_displacement=0.0, stats={"dim": 3})
    (model,) = model_interfaces(run, 1, stored.cut_heights())
    # the same number a study's discrepancy job computes
    assert d == pytest.approx(rkhs(model, stored.snapshots[0], sigma_w=0.1).D, rel=1e-9)
    assert main(["distance", "--pixel-size", "0.01", "--origin", "0", "0",
                 str(tmp_path / "model.vtp"), str(out / "volume_0.tif")]) == 2
    assert "a volume needs pixel_size [dx, dy, dz]" in capsys.readouterr().err
