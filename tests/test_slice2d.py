"""The 2D slice of a 3D study (issue 40 item 4, bayescalib.models.fsi.slice2d): the
mid-plane geometry, the inflow mappings, the recording's files (surfaces and mid-plane
B-scans) and the 2D study made from a 3D one, read by the observe stage the way a
study reads them. No solve: the "run" is a made-up half-ellipsoid pushed downstream."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest

from bayescalib.geometry.interface import Interface
from bayescalib.io.observation_store import read_observations
from bayescalib.io.observations import read_interface
from bayescalib.io.runrecord import LoadingResult, SolveResult
from bayescalib.models.fsi.duct import duct_flow_rate, duct_flux_per_width
from bayescalib.models.fsi.slice2d import (
    midplane_geometry,
    midplane_section,
    midplane_z,
    slice_inflow_rate,
    slice_study_config,
    write_surface_recording,
)
from bayescalib.stages.observe import observe
from bayescalib.study import Study

GEO3 = {"dim": 3}  # the default 3D flow cell: 2 x 1 x 1 mm, colony 0.6 x 0.4 x 0.6 at x = 1


def _half_ellipsoid(n: int = 8, a: float = 0.3, b: float = 0.4, c: float = 0.3,
                    xc: float = 1.0, zc: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """The default colony's surface: rings of constant polar angle from the top (one
    vertex) to the floor (y = 0), triangles oriented out of the colony."""
    pts = [[xc, b, zc]]
    rings = []
    for i in range(1, n + 1):
        th = 0.5 * math.pi * i / n
        ph = np.linspace(0.0, 2 * math.pi, 4 * n, endpoint=False)
        ring = np.column_stack([xc + a * math.sin(th) * np.cos(ph),
                                np.full(ph.size, b * math.cos(th)),
                                zc + c * math.sin(th) * np.sin(ph)])
        rings.append(np.arange(len(pts), len(pts) + ph.size))
        pts.extend(ring.tolist())
    pts = np.array(pts)
    tri = []
    m = 4 * n
    for k in range(m):
        tri.append([0, rings[0][k], rings[0][(k + 1) % m]])
    for r0, r1 in itertools.pairwise(rings):
        for k in range(m):
            k1 = (k + 1) % m
            tri += [[r0[k], r1[k], r1[k1]], [r0[k], r1[k1], r0[k1]]]
    tri = np.array(tri)
    p = pts[tri]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    flip = np.einsum("ij,ij->i", normal, p.mean(axis=1) - [xc, 0, zc]) < 0
    tri[flip] = tri[flip][:, ::-1]
    return pts, tri


def _run(shift: float = 0.02, factors=(0.5, 1.0)) -> SolveResult:
    ref, tri = _half_ellipsoid()
    loads = []
    for f in factors:
        cur = ref.copy()
        cur[:, 0] += shift * f * ref[:, 1] / 0.4  # pushed downstream in proportion to height
        loads.append(LoadingResult(label=f"load_{f:g}", factor=f, value=100.0 * f, current=cur))
    return SolveResult(status="ok", reason="", parameters={"material.E": 400.0},
                       load_fraction=1.0, newton_iterations=3, load_steps=1, wall_time=1.0,
                       interface_reference=ref, interface_current=loads[-1].current,
                       segments=tri, max_displacement=shift, stats={"dim": 3}, loadings=loads)


def test_duct_flux_per_width_sums_to_the_rate_and_is_the_plane_flow_far_from_the_walls():
    z = np.linspace(0.0, 1.0, 4001)
    q = duct_flux_per_width(z, 1.0, 1.0)
    assert np.trapezoid(q, z) == pytest.approx(duct_flow_rate(1.0, 1.0), rel=1e-6)
    assert q[0] == pytest.approx(0.0, abs=1e-12) and q[-1] == pytest.approx(0.0, abs=1e-12)
    # the middle of a wide duct: plane Poiseuille, H^3 / 12 per unit G / mu
    assert duct_flux_per_width(5.0, 1.0, 10.0) == pytest.approx(1.0 / 12.0, rel=1e-5)  # series cut at 40 terms


def test_the_midplane_geometry_and_the_inflow_mappings():
    assert midplane_geometry(GEO3) == {"dim": 2, "shape": "half_ellipse", "length": 2.0,
                                       "channel_height": 1.0, "width": 0.6, "height": 0.4,
                                       "centre": 1.0}
    assert midplane_z(GEO3) == 0.5
    assert midplane_z({**GEO3, "centre_z": 0.45}) == 0.45
    assert slice_inflow_rate(GEO3, 100.0, "mean_velocity") == pytest.approx(100.0)
    wide = {**GEO3, "channel_width": 2.0}
    assert slice_inflow_rate(wide, 100.0, "mean_velocity") == pytest.approx(50.0)
    # the square duct's core carries 1.439 times the mean flux per unit width
    assert slice_inflow_rate(GEO3, 100.0, "midplane_flux") == pytest.approx(143.93, abs=0.01)
    # symmetry side walls: a uniform profile across the width, both mappings Q / W
    slip = {**GEO3, "side_walls": "slip"}
    assert slice_inflow_rate(slip, 100.0, "midplane_flux") == pytest.approx(100.0)
    with pytest.raises(ValueError, match="inflow mapping"):
        slice_inflow_rate(GEO3, 100.0, "centreline")
    with pytest.raises(ValueError, match="geometry.dim: 3"):
        midplane_geometry({"dim": 2})


def test_the_midplane_section_of_the_colony_is_its_half_ellipse():
    ref, tri = _half_ellipsoid()
    sec = midplane_section(Interface(ref, tri), GEO3)
    x, y = sec.points.T
    assert x[0] < x[-1]  # upstream foot first
    assert np.abs(((x - 1.0) / 0.3) ** 2 + (y / 0.4) ** 2 - 1.0).max() < 1e-9  # vertices cut
    assert y.min() == pytest.approx(0.0, abs=1e-12) and y.max() == pytest.approx(0.4)


def test_the_recording_and_the_2d_study_made_from_the_3d_one(tmp_path):
    rec_dir = tmp_path / "rec"
    # noise well below the smallest triangles (about 10 um near the pole), so the noisy
    # surface does not fold
    info = write_surface_recording(_run(), GEO3, rec_dir, noise_sigma=0.0005, seed=3,
                                   truth={"material.E": 400.0, "material.nu": 0.3})
    assert json.loads((rec_dir / "recording.json").read_text()) == info
    assert [s["label"] for s in info["snapshots"]] == ["load_0.5", "load_1"]
    clean = read_interface(rec_dir / "truth_load_1.vtp")
    noisy = read_interface(rec_dir / "load_1.vtp")
    assert noisy.dim == 3 and noisy.cells.shape == clean.cells.shape
    assert np.std(noisy.points - clean.points) == pytest.approx(0.0005, rel=0.1)
    sec = read_interface(rec_dir / "load_1.csv")
    assert sec.dim == 2 and sec.points[0, 0] < sec.points[-1, 0]
    # the section of the noisy surface lies within a few sigma of the clean section
    from bayescalib.geometry.projection import closest_points

    dist, _, _ = closest_points(sec.points, midplane_section(clean, GEO3))
    assert np.abs(dist).max() < 0.01

    files = [{"path": str(rec_dir / s["surface"]), "label": s["label"],
              "load": s["inflow_rate_mm3_per_s"]} for s in info["snapshots"]]
    cfg3 = {
        "study": "t3", "forward_model": {
            "type": "fsi", "loadings": {"parameter": "inflow.rate", "nominal": 100.0,
                                        "factors": [0.5, 1.0]},
            "fsi": {"geometry": {"dim": 3}, "mesh": {"preset": "very_coarse"},
                    "inflow": {"rate": 100.0}}},
        "parameters": [
            {"name": "E", "unit": "Pa", "target": "material.E",
             "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0}},
            {"name": "nu", "unit": "-", "target": "material.nu",
             "prior": {"type": "uniform", "lo": -0.8, "hi": 0.45}}],
        "observations": {"source": "files", "files": files,
                         "domain": [[0.0, 2.0], [0.0, 1.0], [0.0, 1.0]]},
        "measures": ["cpp"], "likelihood": {"sigma_n2": 4.0e-6}}
    sections = [rec_dir / s["section"] for s in info["snapshots"]]
    cfg2 = slice_study_config(cfg3, sections, "midplane_flux", study="t2")
    fsi2 = cfg2["forward_model"]["fsi"]
    assert fsi2["geometry"] == midplane_geometry(GEO3) and fsi2["mesh"] == {"preset": "coarse"}
    q = slice_inflow_rate(GEO3, 100.0, "midplane_flux")
    assert fsi2["inflow"]["rate"] == pytest.approx(q)
    assert cfg2["forward_model"]["loadings"]["nominal"] == pytest.approx(q)
    assert [f["load"] for f in cfg2["observations"]["files"]] == pytest.approx([q / 2, q])
    assert [f["label"] for f in cfg2["observations"]["files"]] == ["load_0.5", "load_1"]
    assert cfg2["observations"]["domain"] == [[0.0, 2.0], [0.0, 1.0]]
    assert cfg2["parameters"] == cfg3["parameters"] and cfg2["likelihood"] == cfg3["likelihood"]
    assert cfg3["forward_model"]["fsi"]["geometry"] == {"dim": 3}  # not modified

    # both studies are valid and their observe stage reads the files: surfaces, sections
    for cfg, dim in ((cfg3, 3), (cfg2, 2)):
        study = Study(cfg)
        observe(study.config["observations"], tmp_path / f"obs{dim}.h5")
        obs = read_observations(tmp_path / f"obs{dim}.h5")
        assert [s.dim for s in obs.snapshots] == [dim, dim]
        assert obs.labels == ["load_0.5", "load_1"]

    # the 2D colony from the zero-flow section (geometry.shape: scan)
    scan = slice_study_config(cfg3, sections, "mean_velocity", study="t2s",
                              scan=rec_dir / "rest.csv")
    geo = scan["forward_model"]["fsi"]["geometry"]
    assert geo["shape"] == "scan" and geo["scan"]["path"] == str(rec_dir / "rest.csv")
    assert [f["load"] for f in scan["observations"]["files"]] == pytest.approx([50.0, 100.0])
    outline = Study(scan).config["forward_model"]["fsi"][
        "geometry"]["outline"]
    assert np.ptp(np.asarray(outline)[:, 0]) == pytest.approx(0.6, abs=0.01)


def test_a_2d_study_is_not_sliced_and_sections_must_match_the_files():
    cfg = {"study": "x", "forward_model": {"type": "fsi", "fsi": {}},
           "observations": {"source": "files", "files": [{"path": "a.vtp"}]}}
    with pytest.raises(ValueError, match="not 3D"):
        slice_study_config(cfg, ["a.csv"], "mean_velocity", study="y")
    cfg["forward_model"]["fsi"] = {"geometry": {"dim": 3}}
    with pytest.raises(ValueError, match="one section per file"):
        slice_study_config(cfg, [], "mean_velocity", study="y")
    cfg["observations"] = {"source": "synthetic"}
    with pytest.raises(ValueError, match="from files"):
        slice_study_config(cfg, ["a.csv"], "mean_velocity", study="y")


def test_the_noise_floor_is_sigma_squared_per_point_and_what_the_section_sees():
    from bayescalib.measures import noise_floor

    ref, tri = _half_ellipsoid()
    surf = Interface(ref, tri)
    sigma = 0.001
    # cpp: one distance per model point, about sigma^2 (less: a point's closest point
    # may lie on a neighbour's triangle; more at the rim, where the noise is tangential)
    cpp = noise_floor("cpp", surf, sigma, draws=8, seed=1)
    assert 0.5 * sigma**2 < cpp < 1.5 * sigma**2
    assert noise_floor("cpp", surf, sigma, draws=8, seed=1) == cpp  # seeded
    # rkhs: the noise current's squared norm, here with a B-scan cut from the surface
    sec = noise_floor("rkhs", surf, sigma, draws=4, seed=1, sigma_w=0.1,
                      transform=lambda s: midplane_section(s, GEO3))
    assert sec > 0 and noise_floor("rkhs", surf, 2 * sigma, draws=4, seed=1, sigma_w=0.1,
                                   transform=lambda s: midplane_section(s, GEO3)) > 2 * sec
    with pytest.raises(ValueError, match="draws"):
        noise_floor("cpp", surf, sigma, draws=0)


def test_file_loads_out_of_the_loadings_order_are_refused(tmp_path):
    """Snapshots are paired with the loadings by their order: a file whose load is not
    its loading's value (listed out of order, or in other units) is a config error."""
    from bayescalib.config import ConfigError
    from bayescalib.io.observations import write_interface_vtk

    ref, tri = _half_ellipsoid()
    write_interface_vtk(tmp_path / "s.vtp", Interface(ref, tri))

    def cfg(loads, factors=(0.5, 1.0), nominal=None, calibrated=False):
        params = [{"name": "E", "unit": "Pa", "target": "material.E",
                   "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0}}]
        if calibrated:
            params.append({"name": "Q", "unit": "mm^3/s", "target": "inflow.rate",
                           "prior": {"type": "uniform", "lo": 50.0, "hi": 150.0}})
        return {"study": "t", "forward_model": {
            "type": "fsi", "loadings": {"parameter": "inflow.rate", "nominal": nominal,
                                        "factors": list(factors)},
            "fsi": {"geometry": {"dim": 3}, "mesh": {"preset": "very_coarse"},
                    "inflow": {"rate": 100.0}}},
            "parameters": params,
            "observations": {"source": "files", "files": [
                {"path": str(tmp_path / "s.vtp"), "load": v} for v in loads]},
            "measures": ["cpp"]}

    Study(cfg([50.0, 100.0]))
    Study(cfg([None, 100.0]))
    Study(cfg([25.0, 50.0], nominal=50.0))
    with pytest.raises(ConfigError, match=r"files\[0\].load is 100 but its loading is 50 "
                                          r"\(factor 0.5 x nominal 100 of inflow.rate\)"):
        Study(cfg([100.0, 50.0]))
    with pytest.raises(ConfigError, match=r"files\[0\].load is 50 but its loading is 100"):
        Study(cfg([50.0], factors=(1.0,)))  # one loading: the model's inflow.rate
    # the loaded parameter calibrated: only the ratios are known
    Study(cfg([60.0, 120.0], calibrated=True))
    with pytest.raises(ConfigError, match=r"files\[1\].load is 100 but its loading is 120"):
        Study(cfg([60.0, 100.0], calibrated=True))


def test_the_3d_models_inflow_rate_is_a_volume_rate():
    """Bug found here: the unit check read every fsi inflow rate in mm^2/s, so a 3D study
    calibrating its (volume) rate in mm^3/s was refused, and mm^2/s was let through."""
    from bayescalib.config import ConfigError
    from bayescalib.models.units import fsi_target_unit, validate_fsi_units

    assert fsi_target_unit("inflow.rate") == "mm^2/s"
    assert fsi_target_unit("inflow.rate", 3) == "mm^3/s"
    assert fsi_target_unit("geometry.depth", 3) == "mm" and fsi_target_unit("material.E", 3) == "Pa"
    q = [{"name": "Q", "unit": "mm^3/s", "target": "inflow.rate",
          "prior": {"type": "uniform", "lo": 50.0, "hi": 150.0}}]
    validate_fsi_units(q, dim=3)
    with pytest.raises(ConfigError, match="reads its target inflow.rate in mm\\^2/s"):
        validate_fsi_units(q)
    with pytest.raises(ConfigError, match="reads its target inflow.rate in mm\\^3/s"):
        validate_fsi_units([{**q[0], "unit": "mm^2/s"}], dim=3)


def test_the_posterior_comparison_figure(tmp_path):
    from bayescalib.plotting.comparison import plot_posterior_comparison

    rng = np.random.default_rng(0)
    posts = {f"model {k}": (rng.normal([400.0 + 100 * k, 0.3], [50.0, 0.1], (300, 2)),
                            np.ones(300)) for k in range(3)}
    out = plot_posterior_comparison(posts, ["E", "nu"], ["Pa", "-"], [400.0, 0.3],
                                    tmp_path / "c.png", title="t")
    assert [p.name for p in out] == ["c.png"] and (tmp_path / "c.png").stat().st_size > 1000
    with pytest.raises(ValueError, match="two parameters"):
        plot_posterior_comparison(posts, ["E"], ["Pa"], [400.0], tmp_path / "d.png")
