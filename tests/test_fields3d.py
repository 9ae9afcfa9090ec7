"""The fields output and figure of the 3D model (issue 40): the VTU of a 3D solve (each
tetrahedron refined into eight at its edge midpoints, the P2 fields at its ten nodes),
its section by the colony's mid-plane and the fields figure drawn from it, and the
workflow's fields rules for a 3D study. The 2D writer's output is the one it was.

One 3D solve on the very coarse mesh (a few seconds) serves the whole module."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ngsolve")

from _workflow_helpers import REPO
from _workflow_helpers import setup_study as _setup
from _workflow_helpers import smk as _smk

from bayescalib.io.runrecord import write_run
from bayescalib.models.fsi.duct import duct_flow_rate, duct_velocity
from bayescalib.models.fsi.model import FSIModel
from bayescalib.models.fsi.vtu import _REF_TET, _SUBTETS, write_fields_vtu
from bayescalib.stages.figures import field_figure, read_vtu_fields, section_fields

CFG3 = {"geometry": {"dim": 3}, "mesh": {"preset": "very_coarse"}}
#: the default 3D channel (mm): length, height, width; the colony's centre and semi-axes
L, H, W = 2.0, 1.0, 1.0
XC, ZC, A, B, C = 1.0, 0.5, 0.3, 0.4, 0.3
RATE = 100.0  # mm^3/s, the default inflow


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """A 3D solve at the defaults, its VTU and run record."""
    tmp = tmp_path_factory.mktemp("fields3d")
    model = FSIModel(CFG3)
    res = model.solve()
    assert res.ok, res.reason
    g = model.config["geometry"]
    assert (g["length"], g["channel_height"], g["channel_width"]) == (L, H, W)
    assert (g["centre"], g["width"] / 2, g["height"], g["depth"] / 2) == (XC, A, B, C)
    assert model.config["inflow"]["rate"] == RATE
    model.write_vtu(tmp / "fields.vtu")
    write_run(tmp / "run.h5", res)
    return model, tmp / "fields.vtu", tmp / "run.h5"


@pytest.fixture(scope="module")
def fields(solved):
    return read_vtu_fields(solved[1])


def _faces(tets):
    return np.vstack([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]],
                      tets[:, [1, 2, 3]]])


def _volumes(points, tets):
    p = points[tets]
    return np.linalg.det(np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]],
                                  axis=1)) / 6.0


def test_the_reference_nodes_are_ngsolves_vertices_and_edge_midpoints(solved):
    """Nodes 0-3 of every tetrahedron are its vertices in NGSolve's order, nodes 4-9 the
    points of its edges 30, 31, 32, 01, 02, 12 at their middle (on a curved element the
    curved edge's; the straight elements' are the chords' midpoints)."""
    import ngsolve as ng

    mesh = solved[0].solver.mesh
    mips = mesh.MapToAllElements(ng.IntegrationRule(points=_REF_TET, weights=[0.0] * 10),
                                 ng.VOL)
    xyz = np.asarray(ng.CF((ng.x, ng.y, ng.z))(mips)).reshape(-1, 10, 3)
    V = np.array([v.point for v in mesh.vertices])
    pairs = [(3, 0), (3, 1), (3, 2), (0, 1), (0, 2), (1, 2)]
    dev = []
    for k, el in enumerate(mesh.Elements(ng.VOL)):
        vn = [v.nr for v in el.vertices]
        np.testing.assert_allclose(xyz[k, :4], V[vn], atol=1e-12)
        # NGSolve's edges of the element are those pairs, in that order
        assert [sorted(v.nr for v in mesh[e].vertices) for e in el.edges] == \
            [sorted((vn[i], vn[j])) for i, j in pairs]
        chords = np.array([0.5 * (V[vn[i]] + V[vn[j]]) for i, j in pairs])
        dist = np.linalg.norm(xyz[k, 4:, None, :] - chords[None], axis=2)
        # each mapped midpoint is nearest its own edge's chord midpoint
        assert np.array_equal(dist.argmin(axis=1), np.arange(6))
        dev.append(dist.diagonal().max())
    dev = np.array(dev)
    assert np.mean(dev < 1e-12) > 0.5  # the straight elements (away from the colony)
    assert dev.max() < 0.02  # the curved ones: the edge bows off its chord a little


def test_the_sub_tetrahedra_fill_the_tetrahedron():
    ref = np.array(_REF_TET)
    vols = _volumes(ref, _SUBTETS)
    assert np.allclose(vols, vols[0]) and vols.sum() == pytest.approx(_volumes(ref, np.array(
        [[0, 1, 2, 3]]))[0])


def test_the_3d_vtu_holds_the_fields_on_the_refined_tetrahedra(solved, fields):
    mesh = solved[0].solver.mesh
    pts, tets = fields["points"], fields["tetrahedra"]
    n = mesh.nv + mesh.nedge  # a node per vertex and per edge: merged, none twice or lost
    assert pts.shape == (n, 3) and tets.shape == (8 * mesh.ne, 4)
    assert fields["velocity"].shape == fields["displacement"].shape == (n, 3)
    assert fields["pressure"].shape == (n,) and fields["region"].shape == (8 * mesh.ne,)
    assert len(np.unique(np.round(pts / 1e-9), axis=0)) == n
    assert np.array_equal(np.unique(tets), np.arange(n))
    vol = _volumes(pts, tets)
    assert vol.min() > 0  # VTK's orientation
    assert vol.sum() == pytest.approx(L * H * W, rel=1e-9)  # the walls do not move


def test_the_inflow_carries_the_rate_and_the_walls_hold_the_fluid(fields):
    pts, v = fields["points"], fields["velocity"]
    faces = _faces(fields["tetrahedra"])
    inlet = faces[(pts[faces][:, :, 0] == 0.0).all(axis=1)]
    p = pts[inlet]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    assert area.sum() == pytest.approx(H * W, rel=1e-12)
    q = (area * v[inlet][:, :, 0].mean(axis=1)).sum()
    # the developed duct flow at the same nodes, integrated alike: what the piecewise-
    # linear picture of the P2 profile can carry (the very coarse inlet's linear
    # quadrature is 9 % short of the rate)
    u = RATE * duct_velocity(p[:, :, 1], p[:, :, 2], H, W) / duct_flow_rate(H, W)
    q_nodes = (area * u.mean(axis=1)).sum()
    assert q == pytest.approx(q_nodes, rel=0.01)
    assert q == pytest.approx(RATE, rel=0.12)
    assert np.abs(v[inlet][:, :, 1:]).max() < 1e-12  # the inflow is along x
    # no slip: zero on floor, top and side walls past the inlet's first layer of
    # elements (whose edges carry the inflow profile's projection at the inlet's rim)
    wall = ((np.abs(pts[:, 1]) < 1e-12) | (np.abs(pts[:, 1] - H) < 1e-12)
            | (np.abs(pts[:, 2]) < 1e-12) | (np.abs(pts[:, 2] - W) < 1e-12))
    assert wall.sum() > 100
    assert np.abs(v[wall & (pts[:, 0] > 0.5)]).max() < 1e-10
    assert np.linalg.norm(v, axis=1).max() > 1.5 * RATE / (H * W)  # and flow inside


def test_the_displacement_is_the_colonys(fields):
    pts, d = fields["points"], fields["displacement"]
    dm = np.linalg.norm(d, axis=1)
    solid_nodes = np.unique(fields["tetrahedra"][fields["region"] > 0])
    assert dm[solid_nodes].max() == dm.max() > 1e-3  # mm: it bends
    outer = ((np.abs(pts[:, 1]) < 1e-12) & (np.abs(pts[:, 0] - XC) > A + 1e-6)) \
        | (np.abs(pts[:, 1] - H) < 1e-12) | (np.abs(pts[:, 2]) < 1e-12) \
        | (np.abs(pts[:, 2] - W) < 1e-12) | (pts[:, 0] < 1e-12) | (pts[:, 0] > L - 1e-12)
    assert np.abs(d[outer]).max() == 0.0
    far = np.abs(pts[:, 0] - XC) > A + 0.6
    assert far.sum() > 20 and dm[far].max() == 0.0


def test_the_region_cell_data_is_the_colony(fields):
    pts, tets, reg = fields["points"], fields["tetrahedra"], fields["region"]
    assert set(np.unique(reg)) == {0, 1}
    c = pts[tets].mean(axis=1)
    r = ((c[:, 0] - XC) / A) ** 2 + (c[:, 1] / B) ** 2 + ((c[:, 2] - ZC) / C) ** 2
    assert r[reg == 1].max() < 1.2 and r[reg == 0].min() > 0.8  # (deformed a little)
    vol = _volumes(pts, tets)
    assert vol[reg == 1].sum() == pytest.approx(2.0 / 3.0 * np.pi * A * B * C, rel=0.05)


def test_the_section_lies_in_its_plane_and_covers_the_channel(fields):
    # linear fields pass through the section exactly: the points' own coordinates
    probe = {**fields, "velocity": fields["points"], "pressure": fields["points"][:, 2]}
    sec = section_fields(probe, ZC)
    np.testing.assert_allclose(sec["pressure"], ZC, atol=1e-12)  # z of every point
    np.testing.assert_allclose(sec["velocity"][:, :2], sec["points"], atol=1e-12)
    P, T = sec["points"], sec["triangles"]
    assert len(np.unique(np.round(P / 1e-9), axis=0)) == len(P)
    p = P[T]
    area = 0.5 * np.abs((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                        - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    assert area.sum() == pytest.approx(L * H, rel=1e-9)  # the whole channel, no overlap
    _, count = np.unique(np.sort(np.vstack([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]),
                                     axis=1), axis=0, return_counts=True)
    assert count.max() <= 2
    # the colony's section: the half ellipse of semi-axes A, B (deformed a little)
    assert area[sec["region"] > 0].sum() == pytest.approx(np.pi * A * B / 2, rel=0.06)
    with pytest.raises(ValueError, match="misses"):
        section_fields(fields, W + 1.0)


def test_the_fields_figure_of_a_3d_solve_is_its_mid_plane(solved, tmp_path):
    from bayescalib.stages import figures

    _, vtu, run = solved
    plots = {"formats": ["png"], "dpi": 60}
    (png,) = field_figure(vtu, run, plots, tmp_path / "fields", section_z=ZC)
    assert Path(png).stat().st_size > 10_000
    # without section_z: the middle of the colony at rest, here z_c
    (png,) = field_figure(vtu, run, plots, tmp_path / "default")
    assert Path(png).stat().st_size > 10_000
    from bayescalib.io.runrecord import read_run

    _, curve, z = figures._section(read_vtu_fields(vtu), read_run(run), None)
    assert z == pytest.approx(ZC, abs=0.02)
    # the interface's section runs over the colony from foot to foot
    assert curve[0, 0] == pytest.approx(XC - A, abs=0.03)
    assert curve[-1, 0] == pytest.approx(XC + A, abs=0.03)
    assert curve[:, 1].max() == pytest.approx(B, abs=0.03)


_OLD_SUBTRIANGLES = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]])


def _write_fields_vtu_2d_before(path, solver, pressure_scale=1.0e-3):
    """The 2D writer before the 3D one (commit 77d3489), verbatim but for the merge,
    inlined: the reference of the 2D output."""
    import ngsolve as ng
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    mesh = solver.mesh
    ref = [(1.0, 0.0), (0.0, 1.0), (0.0, 0.0), (0.5, 0.5), (0.0, 0.5), (0.5, 0.0)]
    mips = mesh.MapToAllElements(ng.IntegrationRule(points=ref, weights=[0.0] * 6), ng.VOL)
    xy = np.asarray(ng.CF((ng.x, ng.y))(mips), dtype=float).reshape(-1, 2)
    vel = np.asarray(solver.gfu.components[0](mips), dtype=float).reshape(-1, 2)
    disp = np.zeros_like(xy)
    if solver.i_d is not None:
        disp = np.asarray(solver.gfu.components[solver.i_d](mips), dtype=float).reshape(-1, 2)
    pres = np.zeros(xy.shape[0])
    if solver.i_p is not None:
        pres = np.asarray(solver.gfu.components[solver.i_p](mips), dtype=float).ravel()
        if solver.i_pore is not None:
            pres = pres + np.asarray(solver.gfu.components[solver.i_pore](mips),
                                     dtype=float).ravel()
        pres = pres * pressure_scale
    regions = {name: i for i, name in enumerate(mesh.GetMaterials())}
    reg = np.array([regions[el.mat] for el in mesh.Elements(ng.VOL)], dtype=np.int32)
    n_el = reg.shape[0]
    scale = float(np.max(np.abs(xy))) or 1.0
    keys = np.round(xy / (1e-9 * scale)).astype(np.int64)
    order = np.argsort(reg != 0, kind="stable")
    node_order = (6 * order[:, None] + np.arange(6)).ravel()
    _, first, inverse = np.unique(keys[node_order], axis=0, return_index=True,
                                  return_inverse=True)
    node_of = np.empty(6 * n_el, dtype=np.int64)
    node_of[node_order] = inverse.ravel()
    pick = node_order[first]
    tris = node_of.reshape(n_el, 6)[:, _OLD_SUBTRIANGLES].reshape(-1, 3)
    pts, vel, disp, pres = xy[pick], vel[pick], disp[pick], pres[pick]
    reg = np.repeat(reg, 4)
    pts = np.column_stack([pts + disp, np.zeros(len(pts))])
    offsets = np.arange(0, 3 * len(tris) + 1, 3, dtype=np.int64)
    grid = vtk.vtkUnstructuredGrid()
    p = vtk.vtkPoints()
    p.SetData(numpy_to_vtk(pts, deep=True))
    grid.SetPoints(p)
    ca = vtk.vtkCellArray()
    ca.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
               numpy_to_vtkIdTypeArray(np.ascontiguousarray(tris.ravel()), deep=True))
    grid.SetCells(vtk.VTK_TRIANGLE, ca)
    for name, arr in (("velocity", vel), ("displacement", disp), ("pressure", pres)):
        va = numpy_to_vtk(np.ascontiguousarray(arr), deep=True)
        va.SetName(name)
        grid.GetPointData().AddArray(va)
    ra = numpy_to_vtk(np.asarray(reg, dtype=np.int32), deep=True)
    ra.SetName("region")
    grid.GetCellData().AddArray(ra)
    w = vtk.vtkXMLUnstructuredGridWriter()
    w.SetFileName(str(path))
    w.SetInputData(grid)
    assert w.Write()


def test_the_2d_writer_writes_what_it_wrote(tmp_path):
    model = FSIModel({"mesh": {"preset": "very_coarse"}})
    assert model.solve().ok
    write_fields_vtu(tmp_path / "now.vtu", model.solver)
    _write_fields_vtu_2d_before(tmp_path / "before.vtu", model.solver)
    assert (tmp_path / "now.vtu").read_bytes() == (tmp_path / "before.vtu").read_bytes()
    f = read_vtu_fields(tmp_path / "now.vtu")
    assert "triangles" in f and f["points"].shape[1] == 2 and f["velocity"].shape[1] == 2


SMOKE3D = REPO / "config" / "fsi3d_smoke.yaml"


@pytest.mark.workflow
@pytest.mark.parametrize("synthetic", [True, False])
def test_a_3d_study_solves_and_draws_its_fields(tmp_path, synthetic):
    """A 3D study's dry run has the fields: the ground truth's solve writes them
    (synthetic data) or the solve at the posterior mean (real data), and fig_fields
    draws them in the colony's mid-plane."""
    import re

    import yaml

    study = yaml.safe_load(SMOKE3D.read_text())
    if not synthetic:
        from bayescalib.io.observations import write_interface_vtk
        from bayescalib.models.fsi.geometry3d import reference_surface

        geo = FSIModel(CFG3).config["geometry"]
        surf = reference_surface(geo)
        files = []
        for k, f in enumerate((0.5, 1.0)):
            path = tmp_path / f"scan{k}.vtp"
            write_interface_vtk(path, surf)
            files.append({"path": str(path), "units": "mm", "load": RATE * f})
        study["observations"] = {"source": "files", "files": files}
        for p in study["parameters"]:
            p.pop("ground_truth", None)
    _setup(tmp_path, study)
    proc = _smk(tmp_path, "-n", "-p", "--forceall")
    text = proc.stdout + proc.stderr
    assert re.search(r"^rule fig_fields:", text, flags=re.MULTILINE), text[-3000:]
    solve = "ground_truth" if synthetic else "posterior_mean_solve"
    vtu = "observations/ground_truth.vtu" if synthetic else "posterior_mean/fields.vtu"
    assert re.search(rf"^rule {solve}:\n(?:.+\n)*?\s+output: .*{re.escape(vtu)}", text,
                     flags=re.MULTILINE), text[-3000:]
    block = re.search(r"^rule fig_fields:\n(?:.+\n)+", text, flags=re.MULTILINE).group(0)
    assert vtu in block


def test_the_3d_solve_at_the_posterior_mean_writes_the_fields_its_figure_draws(tmp_path):
    """Real data: the posterior mean's solve (rule posterior_mean_solve, two loadings
    as in the 3D smoke study) writes the 3D VTU, and fig_fields draws its section."""
    import json

    import yaml

    from bayescalib.stages.figures import solve_at_posterior_mean
    from bayescalib.study import Study

    study = Study(yaml.safe_load(SMOKE3D.read_text()))
    params = study.config["parameters"]
    (tmp_path / "posterior.json").write_text(json.dumps({"mean": {"E": 450.0, "nu": 0.25}}))
    solve_at_posterior_mean(tmp_path / "posterior.json", params, study.forward_section(),
                            tmp_path / "run.h5", tmp_path / "fields.vtu")
    f = read_vtu_fields(tmp_path / "fields.vtu")
    assert f["points"].shape[1] == 3 and f["tetrahedra"].shape[1] == 4
    (png,) = field_figure(tmp_path / "fields.vtu", tmp_path / "run.h5",
                          {"formats": ["png"], "dpi": 60}, tmp_path / "fields",
                          at="posterior_mean", parameters=params, section_z=ZC)
    assert Path(png).stat().st_size > 10_000
