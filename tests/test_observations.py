"""Tests of the observation readers, synthetic noise and observation sets."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _interface_shapes import arc, circle, dome
from hypothesis import given, settings
from hypothesis import strategies as st

from bayescalib.geometry.interface import Interface
from bayescalib.io.observations import (
    ObservationError,
    ObservationSet,
    add_noise,
    read_interface,
    read_points,
    write_interface_csv,
    write_interface_vtk,
)


def write(path, text):
    path.write_text(text)
    return path


# ----------------------------------------------------------------------------- CSV
def test_csv_round_trip(tmp_path):
    c = arc(0.4, 37)
    write_interface_csv(tmp_path / "c.csv", c)
    back = read_interface(tmp_path / "c.csv")
    np.testing.assert_array_equal(back.points, c.points)
    np.testing.assert_array_equal(back.cells, c.cells)
    closed = circle(1.0, 20)
    write_interface_csv(tmp_path / "closed.csv", closed)
    back = read_interface(tmp_path / "closed.csv")
    assert back.n_cells == back.n_points == 20


def test_csv_units_and_extra_columns(tmp_path):
    p = write(tmp_path / "m.csv", "id,X,y\n0,0.001,0.0\n1,0.002,0.0005\n")
    c = read_interface(p, units="m")
    np.testing.assert_allclose(c.points, [[1.0, 0.0], [2.0, 0.5]])
    p = write(tmp_path / "um.csv", "x,y,z\n100,0,5\n200,50,5\n")
    np.testing.assert_allclose(read_interface(p, units="um").points, [[0.1, 0.0], [0.2, 0.05]])


@pytest.mark.parametrize(
    "text, match",
    [
        ("", "empty"),
        ("x,y\n", "empty"),
        ("x,y\n0,0\n", "single point"),
        ("x,y\n0,0\nnan,1\n", "NaN/inf.*row 3"),
        ("x,y\n0,0\ninf,1\n", "NaN/inf"),
        ("x,y\n0,0\n1,1\n1,1\n2,0\n", "duplicate consecutive.*row 4"),
        ("x,y\n0,0\n1,1\n1,0\n0,1\n", "intersects itself"),
        ("a,b\n0,0\n1,1\n", "header"),
        ("x,y\n0,0\n1,abc\n", "non-numeric"),
        ("x,y\n0,0\n1\n", "columns"),
        ("x,y,z\n0,0,0\n1,1,1\n", "3D curve"),
    ],
)
def test_csv_bad_input_names_file(tmp_path, text, match):
    p = write(tmp_path / "bad_input.csv", text)
    with pytest.raises(ObservationError, match=match) as info:
        read_interface(p)
    assert "bad_input.csv" in str(info.value)


def test_missing_file_and_unknown_suffix(tmp_path):
    with pytest.raises(ObservationError, match="nothere.csv.*does not exist"):
        read_interface(tmp_path / "nothere.csv")
    p = write(tmp_path / "curve.txt", "x,y\n0,0\n1,1\n")
    with pytest.raises(ObservationError, match="curve.txt.*unknown interface file type"):
        read_interface(p)
    with pytest.raises(ObservationError, match="units"):
        read_interface(write(tmp_path / "u.csv", "x,y\n0,0\n1,1\n"), units="inch")


def test_unit_mismatch_detected_with_domain(tmp_path):
    # a 0.7 mm wide biofilm written in um but read as mm: 700 units in a 2 mm channel
    pts = np.column_stack([np.linspace(650, 1350, 30), 400 * np.sin(np.linspace(0, math.pi, 30))])
    p = tmp_path / "in_um.csv"
    write_interface_csv(p, Interface.polyline(pts))
    domain = [[0.0, 2.0], [0.0, 1.0]]
    with pytest.raises(ObservationError, match="in_um.csv.*unit mismatch.*'um'"):
        read_interface(p, domain=domain)
    c = read_interface(p, units="um", domain=domain)
    assert c.bounds[1, 0] == pytest.approx(1.35)


def test_read_points(tmp_path):
    p = write(tmp_path / "pts.csv", "x,y,nx,ny\n0.5,0,0,1\n1,0,0,2\n")
    pts, dirs = read_points(p)
    np.testing.assert_allclose(pts, [[0.5, 0], [1, 0]])
    np.testing.assert_allclose(dirs, [[0, 1], [0, 2]])
    pts, dirs = read_points(write(tmp_path / "p2.csv", "x,y\n1,2\n"), units="um")
    np.testing.assert_allclose(pts, [[1e-3, 2e-3]])
    assert dirs is None


# ----------------------------------------------------------------------------- VTK
def test_vtk_round_trip_polyline_and_surface(tmp_path):
    c = arc(0.4, 25)
    write_interface_vtk(tmp_path / "c.vtp", c)
    back = read_interface(tmp_path / "c.vtp")
    np.testing.assert_allclose(back.points, c.points)
    assert back.is_chain()
    s = dome(1.0, 2)  # an observed surface: open, its rim on the floor
    write_interface_vtk(tmp_path / "s.vtp", s)
    back = read_interface(tmp_path / "s.vtp", units="m")
    np.testing.assert_allclose(back.points, 1000 * s.points)
    np.testing.assert_array_equal(back.cells, s.cells)


def test_vtk_legacy_and_vtu(tmp_path):
    import vtk

    c = arc(0.3, 12)
    write_interface_vtk(tmp_path / "c.vtp", c)
    r = vtk.vtkXMLPolyDataReader()
    r.SetFileName(str(tmp_path / "c.vtp"))
    r.Update()
    w = vtk.vtkGenericDataObjectWriter()
    w.SetFileName(str(tmp_path / "c.vtk"))
    w.SetInputData(r.GetOutput())
    w.Write()
    np.testing.assert_allclose(read_interface(tmp_path / "c.vtk").points, c.points)
    ug = vtk.vtkAppendFilter()
    ug.AddInputData(r.GetOutput())
    ug.Update()
    w = vtk.vtkXMLUnstructuredGridWriter()
    w.SetFileName(str(tmp_path / "c.vtu"))
    w.SetInputData(ug.GetOutput())
    w.Write()
    np.testing.assert_allclose(read_interface(tmp_path / "c.vtu").points, c.points)


def test_vtk_bad_input(tmp_path):
    p = write(tmp_path / "broken.vtp", "not a vtk file")
    with pytest.raises(ObservationError, match="broken.vtp"):
        read_interface(p)
    bow = Interface.polyline([[0, 0], [1, 1], [1, 0], [0, 1]])
    write_interface_vtk(tmp_path / "bow.vtp", bow)
    with pytest.raises(ObservationError, match="bow.vtp.*intersects itself"):
        read_interface(tmp_path / "bow.vtp")


# ----------------------------------------------------------------------------- images
def disc_mask(n=200, cx=100.3, cy=90.7, r=40.0):
    rows, cols = np.mgrid[0:n, 0:n]
    return (cols - cx) ** 2 + (rows - cy) ** 2 <= r**2


def test_disc_mask_radius_within_one_pixel(tmp_path):
    from skimage import io

    s = 0.01  # mm per pixel
    io.imsave(tmp_path / "disc.png", (disc_mask() * 255).astype(np.uint8), check_contrast=False)
    c = read_interface(tmp_path / "disc.png", pixel_size=s, origin=(1.0, 2.0))
    # centre in mm: x = 1 + 100.3 s, y = 2 + (199 - 90.7) s (row 0 is the top)
    centre = np.array([1.0 + 100.3 * s, 2.0 + (199 - 90.7) * s])
    radii = np.linalg.norm(c.points - centre, axis=1)
    assert np.max(np.abs(radii - 40 * s)) < s  # sub-pixel contour: error below one pixel
    assert abs(np.mean(radii) - 40 * s) < 0.25 * s
    assert c.n_cells == c.n_points  # closed
    # orientation: foreground on the right -> normals point out of the disc
    assert np.mean(np.einsum("md,md->m", c.normals, c.centres - centre) > 0) > 0.99


def test_floor_biofilm_mask_drops_border(tmp_path):
    from skimage import io

    n = 120
    rows, cols = np.mgrid[0:n, 0:n]
    mask = (cols - 60) ** 2 + (rows - (n - 1)) ** 2 <= 35**2  # half disc on the bottom edge
    io.imsave(tmp_path / "floor.tif", mask.astype(np.uint8), check_contrast=False)
    c = read_interface(tmp_path / "floor.tif", pixel_size=1.0, origin=(0, 0))
    assert c.n_cells == c.n_points - 1  # open: the part along the floor is dropped
    assert c.points[:, 1].min() >= -0.01 and np.all(c.normals[:, 1][c.centres[:, 1] > 10] > -1e-9)
    # upstream -> downstream ordering, normals into the fluid (pointing up at the top)
    top = np.abs(c.centres[:, 0] - 60) < 5
    assert np.mean(c.normals[top, 1]) > 0.9
    assert c.points[0, 0] < c.points[-1, 0]
    closed = read_interface(tmp_path / "floor.tif", pixel_size=1.0, origin=(0, 0),
                            drop_border=False)
    assert closed.n_cells == closed.n_points


def test_floor_inside_image_is_dropped(tmp_path):
    from skimage import io

    # half disc (radius 30 px) standing on a floor at row 80; rows below are substrate (background)
    n = 100
    rows, cols = np.mgrid[0:n, 0:n]
    mask = ((cols - 50) ** 2 + (rows - 80) ** 2 <= 30**2) & (rows <= 80)
    io.imsave(tmp_path / "inner.png", (mask * 255).astype(np.uint8), check_contrast=False)
    s = 0.01
    full = read_interface(tmp_path / "inner.png", pixel_size=s, origin=(0, 0))
    assert full.n_cells == full.n_points  # closed around the base
    y_floor = (n - 1 - 80) * s  # row 80 in mm (origin at the bottom-left pixel centre)
    c = read_interface(tmp_path / "inner.png", pixel_size=s, origin=(0, 0), floor=y_floor)
    assert c.n_cells == c.n_points - 1
    assert c.points[:, 1].min() > y_floor + 0.5 * s
    # the kept arc spans the patch: from near x = 20 px to x = 80 px, ordered upstream -> downstream
    assert c.points[0, 0] < 0.25 and c.points[-1, 0] > 0.75
    top = np.abs(c.centres[:, 0] - 0.5) < 0.05
    assert np.mean(c.normals[top, 1]) > 0.9
    with pytest.raises(ObservationError, match="inner.png.*floor"):
        read_interface(tmp_path / "inner.png", pixel_size=s, origin=(0, 0), floor=10.0)


def test_image_bad_input(tmp_path):
    from skimage import io

    io.imsave(tmp_path / "empty.png", np.zeros((20, 20), np.uint8), check_contrast=False)
    with pytest.raises(ObservationError, match="empty.png.*single grey value.*all black"):
        read_interface(tmp_path / "empty.png", pixel_size=0.01, origin=(0, 0))
    io.imsave(tmp_path / "disc.png", (disc_mask() * 255).astype(np.uint8), check_contrast=False)
    with pytest.raises(ObservationError, match="disc.png.*pixel size"):
        read_interface(tmp_path / "disc.png", origin=(0, 0))
    with pytest.raises(ObservationError, match="disc.png.*origin.*bottom-left pixel"):
        read_interface(tmp_path / "disc.png", pixel_size=0.01)
    write(tmp_path / "junk.png", "not an image")
    with pytest.raises(ObservationError, match="junk.png"):
        read_interface(tmp_path / "junk.png", pixel_size=0.01, origin=(0, 0))


# ----------------------------------------------------------------------------- noise, sets
def test_add_noise_statistics_and_seed():
    c = arc(0.4, 2001)
    a = add_noise(c, 0.001, np.random.default_rng(5))
    b = add_noise(c, 0.001, np.random.default_rng(5))
    np.testing.assert_array_equal(a.points, b.points)
    dev = (a.points - c.points).ravel()
    # 4002 samples: the sample std is within 5 % of sigma_obs (std error ~1.1 %)
    assert np.std(dev) == pytest.approx(0.001, rel=0.05)
    assert add_noise(c, 0.0, np.random.default_rng(0)) is c
    with pytest.raises(ObservationError):
        add_noise(c, -1.0, np.random.default_rng(0))


def test_observation_set(tmp_path):
    a, b = arc(0.4, 20), arc(0.41, 20)
    obs = ObservationSet([a, b], ["q50", "q100"], [50.0, 100.0])
    assert len(obs) == 2 and obs.loads == [50.0, 100.0]
    assert ObservationSet([a]).labels == ["snapshot0"]
    with pytest.raises(ObservationError, match="unique"):
        ObservationSet([a, b], ["x", "x"])
    with pytest.raises(ObservationError, match="label"):
        ObservationSet([a, b], ["x"])
    with pytest.raises(ObservationError, match="at least one"):
        ObservationSet([])
    write_interface_csv(tmp_path / "q1.csv", a)
    write_interface_csv(tmp_path / "q2.csv", b)
    s = ObservationSet.from_files([tmp_path / "q1.csv", tmp_path / "q2.csv"], loads=[1, 2])
    assert s.labels == ["q1", "q2"]


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.integers(-3, 3), st.integers(-3, 3)), min_size=0, max_size=8))
def test_random_csv_either_reads_or_raises_clearly(tmp_path_factory, pts):
    """Any small integer curve either reads back exactly or raises ObservationError naming the file."""
    d = tmp_path_factory.mktemp("csv")
    p = d / "rand.csv"
    p.write_text("x,y\n" + "".join(f"{x},{y}\n" for x, y in pts))
    try:
        c = read_interface(p)
    except ObservationError as exc:
        assert "rand.csv" in str(exc)
        return
    arr = np.array(pts, float)
    if c.n_cells == c.n_points:  # closed: last row repeated the first
        arr = arr[:-1]
    np.testing.assert_array_equal(c.points, arr)


@pytest.mark.parametrize("text, name", [
    ("x;y\n0,6;0,0\n0,8;0,3\n1,0;0,0\n", "semicolons"),  # a spreadsheet's decimal commas
    ("x;y\n0.6;0.0\n0.8;0.3\n1.0;0.0\n", "semicolons"),
    ("x\ty\n0.6\t0.0\n0.8\t0.3\n1.0\t0.0\n", "tabs"),
])
def test_a_csv_with_other_separators_is_refused_naming_them(tmp_path, text, name):
    """A CSV saved with ';' (and decimal commas) or tabs was refused as "row 2 has 3
    columns, header has 1" or "a non-numeric value": the separator is what is wrong."""
    path = tmp_path / "scan.csv"
    path.write_text(text)
    with pytest.raises(ObservationError, match=f"separated by {name}") as exc:
        read_interface(path)
    assert "comma-separated" in str(exc.value) and "scan.csv" in str(exc.value)


def test_a_csv_whose_points_are_shuffled_is_refused_saying_they_are_not_in_order(tmp_path):
    """Points not in order along the interface (a spreadsheet sorted by another column)
    make a curve that crosses itself; the message says why: consecutive points lie far
    apart compared with nearest neighbours. An ordered curve that crosses itself (a bow)
    gets no such words."""
    t = np.linspace(0.0, np.pi, 80)
    pts = np.column_stack([1.0 - 0.3 * np.cos(t), 0.4 * np.sin(t)])
    shuffled = pts[np.random.default_rng(0).permutation(len(pts))]
    path = tmp_path / "shuffled.csv"
    path.write_text("x,y\n" + "".join(f"{x:.9f},{y:.9f}\n" for x, y in shuffled))
    with pytest.raises(ObservationError, match="intersects itself.*not in order along the "
                                               "interface"):
        read_interface(path)
    bow = tmp_path / "bow.csv"
    bow.write_text("x,y\n0,0\n1,1\n1,0\n0,1\n")
    with pytest.raises(ObservationError, match="intersects itself") as exc:
        read_interface(bow)
    assert "not in order" not in str(exc.value)
