"""Property-based fuzzing of the observation readers (hypothesis).

Malformed CSV, VTK (.vtp, .vtu, legacy .vtk) and mask images (.png, .tif):
random bytes, random CSV-like text, valid files cut short or with bytes
changed, and random small masks of odd shapes and dtypes. Every input must
either read as an :class:`Interface` or raise :class:`ObservationError` whose
message names the file -- never another exception, never a crash.
Deterministic (``derandomize=True``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from _interface_shapes import arc, dome
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayescalib.geometry.interface import Interface
from bayescalib.io.observations import (
    ObservationError,
    read_interface,
    read_points,
    write_interface_csv,
    write_interface_vtk,
)

FUZZ = settings(max_examples=400, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])
CASES: dict[str, int] = {}


@pytest.fixture(scope="module", autouse=True)
def _quiet_vtk():
    import vtk

    vtk.vtkObject.GlobalWarningDisplayOff()
    yield
    vtk.vtkObject.GlobalWarningDisplayOn()


def _check(path, **options):
    """Read ``path``: an Interface, or an ObservationError naming the file."""
    try:
        iface = read_interface(path, **options)
    except ObservationError as exc:
        assert path.name in str(exc), str(exc)
        return None
    assert isinstance(iface, Interface)
    assert np.isfinite(iface.points).all()
    assert iface.n_points >= 2
    return iface


# --------------------------------------------------------------------------- valid seeds
def _valid_files(d):
    c = arc(0.4, 17)
    write_interface_csv(d / "seed.csv", c)
    write_interface_vtk(d / "seed.vtp", c)
    write_interface_vtk(d / "seed3d.vtp", dome(1.0, 1))
    import vtk

    r = vtk.vtkXMLPolyDataReader()
    r.SetFileName(str(d / "seed.vtp"))
    r.Update()
    w = vtk.vtkPolyDataWriter()
    w.SetFileName(str(d / "seed.vtk"))
    w.SetInputData(r.GetOutput())
    w.Write()
    app = vtk.vtkAppendFilter()
    app.AddInputData(r.GetOutput())
    app.Update()
    w = vtk.vtkXMLUnstructuredGridWriter()
    w.SetFileName(str(d / "seed.vtu"))
    w.SetDataModeToAscii()
    w.SetInputData(app.GetOutput())
    w.Write()
    from skimage import io as skio

    n = 40
    rows, cols = np.mgrid[0:n, 0:n]
    mask = ((cols - 20) ** 2 + (rows - (n - 1)) ** 2 <= 12**2).astype(np.uint8) * 255
    skio.imsave(d / "seed.png", mask, check_contrast=False)
    skio.imsave(d / "seed.tif", mask, check_contrast=False)
    return {p.suffix if p.stem == "seed" else "3d": p.read_bytes()
            for p in d.iterdir() if p.stem.startswith("seed")}


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    return _valid_files(tmp_path_factory.mktemp("seeds"))


def test_seeds_read(seeds, tmp_path):
    for suffix, data in seeds.items():
        p = tmp_path / f"ok{'.vtp' if suffix == '3d' else suffix}"
        p.write_bytes(data)
        assert _check(p, pixel_size=0.01, origin=(0.005, 0.005)) is not None, suffix


SUFFIXES = [".csv", ".vtp", ".vtu", ".vtk", ".png", ".tif"]


@FUZZ
@given(suffix=st.sampled_from(SUFFIXES), data=st.binary(max_size=600))
def test_random_bytes(tmp_path, suffix, data):
    CASES["random bytes"] = CASES.get("random bytes", 0) + 1
    p = tmp_path / f"random{suffix}"
    p.write_bytes(data)
    _check(p, pixel_size=0.01, origin=(0.005, 0.005))


@FUZZ
@given(suffix=st.sampled_from([*SUFFIXES, "3d"]), data=st.data())
def test_damaged_valid_files(seeds, tmp_path, suffix, data):
    """Valid files cut short, with bytes changed, inserted or removed."""
    raw = bytearray(seeds[suffix])
    how = data.draw(st.sampled_from(["cut", "flip", "insert", "delete", "cut+flip"]))
    if "cut" in how:
        raw = raw[: data.draw(st.integers(0, len(raw)))]
    if "flip" in how and raw:
        for _ in range(data.draw(st.integers(1, 8))):
            i = data.draw(st.integers(0, len(raw) - 1))
            raw[i] = data.draw(st.integers(0, 255))
    if how == "insert":
        i = data.draw(st.integers(0, len(raw)))
        raw[i:i] = data.draw(st.binary(min_size=1, max_size=40))
    if how == "delete" and raw:
        i = data.draw(st.integers(0, len(raw) - 1))
        del raw[i: i + data.draw(st.integers(1, 64))]
    CASES["damaged valid files"] = CASES.get("damaged valid files", 0) + 1
    p = tmp_path / f"damaged{'.vtp' if suffix == '3d' else suffix}"
    p.write_bytes(bytes(raw))
    _check(p, pixel_size=0.01, origin=(0.005, 0.005))


CELL = st.one_of(
    st.integers(-5, 5).map(str), st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["", " ", "x", "y", "z", "nan", "inf", "-inf", "1e309", "1,5", '"1"', "#",
                     "\ufeffx", "NaN", "0x1", "1_0", "--1", "1e", "\t2"]),
)
ROW = st.lists(CELL, min_size=0, max_size=4).map(",".join)


@FUZZ
@given(header=st.sampled_from(["x,y", "x,y,z", "X,Y", "y,x", "id,x,y", "x", "x,y,nx,ny", "",
                               "# comment\nx,y"]),
       rows=st.lists(ROW, max_size=8),
       newline=st.sampled_from(["\n", "\r\n", "\r"]))
def test_csv_like_text(tmp_path, header, rows, newline):
    CASES["CSV-like text"] = CASES.get("CSV-like text", 0) + 1
    p = tmp_path / "text.csv"
    p.write_text(newline.join([header, *rows]) + newline, newline="")
    _check(p)
    try:
        pts, _ = read_points(p)
        assert np.isfinite(pts).all()
    except ObservationError as exc:
        assert "text.csv" in str(exc)


@FUZZ
@given(
    shape=st.sampled_from([(1, 1), (1, 7), (7, 1), (2, 2), (5, 9), (16, 16), (12, 12, 3),
                           (10, 10, 4), (3, 4, 2)]),
    dtype=st.sampled_from([np.uint8, np.uint16, np.float32, bool]),
    suffix=st.sampled_from([".png", ".tif"]),
    data=st.data(),
)
def test_random_masks(tmp_path, shape, dtype, suffix, data):
    """Random small images: speckle, empty, full, single pixel, lines, odd channel counts."""
    from skimage import io as skio

    kind = data.draw(st.sampled_from(["noise", "zeros", "ones", "pixel", "row", "col"]))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    arr = np.zeros(shape)
    if kind == "noise":
        arr = rng.random(shape) > 0.5
    elif kind == "ones":
        arr = np.ones(shape)
    elif kind == "pixel":
        arr[tuple(int(rng.integers(0, s)) for s in shape)] = 1
    elif kind == "row":
        arr[shape[0] // 2] = 1
    elif kind == "col" and len(shape) > 1:
        arr[:, shape[1] // 2] = 1
    if dtype is bool:
        img = arr.astype(bool)
    elif np.issubdtype(dtype, np.integer):
        img = (arr * np.iinfo(dtype).max).astype(dtype)
    else:
        img = arr.astype(dtype)
    if suffix == ".png" and (dtype in (np.float32, bool) or (len(shape) == 3 and shape[2] == 2)):
        img = (np.asarray(arr) * 255).astype(np.uint8)
        if len(shape) == 3 and shape[2] == 2:
            img = img[..., 0]
    p = tmp_path / f"mask{suffix}"
    try:
        skio.imsave(p, img, check_contrast=False)
    except Exception:  # noqa: BLE001 - some dtype/shape combinations cannot be written
        return
    CASES["random masks"] = CASES.get("random masks", 0) + 1
    pixel = data.draw(st.sampled_from([0.01, 1.0, 0.0, -1.0, math.nan, math.inf, 1e-300]))
    floor = data.draw(st.sampled_from([None, 0.0, 0.05, -1.0, math.nan]))
    origin = data.draw(st.sampled_from([None, (0.0, 0.0), (1.0, 2.0), (math.nan, 0.0), (1.0,)]))
    _check(p, pixel_size=pixel, floor=floor, origin=origin,
           drop_border=data.draw(st.booleans()))


_VTK_TYPES = {"vertex": 1, "line": 3, "polyline": 4, "triangle": 5, "polygon": 7}


def _vtk_text(suffix, pts, cells, kind):
    """A hand-written ASCII VTK file (writing odd content with VTK itself can crash)."""
    flat = " ".join(repr(float(v)) for p in pts for v in p)
    n = len(pts)
    conn = " ".join(str(i) for c in cells for i in c)
    offsets = " ".join(str(v) for v in np.cumsum([len(c) for c in cells]))
    if suffix == ".vtk":
        section = {"vertex": "VERTICES", "triangle": "POLYGONS", "polygon": "POLYGONS"}.get(
            kind, "LINES")
        body = "\n".join(f"{len(c)} " + " ".join(map(str, c)) for c in cells)
        size = sum(len(c) + 1 for c in cells)
        return (f"# vtk DataFile Version 3.0\nfuzz\nASCII\nDATASET POLYDATA\n"
                f"POINTS {n} float\n{flat}\n{section} {len(cells)} {size}\n{body}\n")
    arrays = (f'<DataArray type="Int64" Name="connectivity" format="ascii">{conn}</DataArray>'
              f'<DataArray type="Int64" Name="offsets" format="ascii">{offsets}</DataArray>')
    points = (f'<Points><DataArray type="Float64" NumberOfComponents="3" format="ascii">'
              f"{flat}</DataArray></Points>")
    if suffix == ".vtu":
        types = " ".join(str(_VTK_TYPES[kind]) for _ in cells)
        return ('<?xml version="1.0"?><VTKFile type="UnstructuredGrid" version="0.1">'
                f'<UnstructuredGrid><Piece NumberOfPoints="{n}" NumberOfCells="{len(cells)}">'
                f"{points}<Cells>{arrays}"
                f'<DataArray type="UInt8" Name="types" format="ascii">{types}</DataArray>'
                "</Cells></Piece></UnstructuredGrid></VTKFile>")
    tag = {"vertex": "Verts", "triangle": "Polys", "polygon": "Polys"}.get(kind, "Lines")
    counts = {t: (len(cells) if t == tag else 0) for t in ("Verts", "Lines", "Strips", "Polys")}
    attrs = " ".join(f'NumberOf{t}="{c}"' for t, c in counts.items())
    return ('<?xml version="1.0"?><VTKFile type="PolyData" version="0.1">'
            f'<PolyData><Piece NumberOfPoints="{n}" {attrs}>{points}'
            f"<{tag}>{arrays}</{tag}></Piece></PolyData></VTKFile>")


@FUZZ
@given(
    pts=st.lists(st.tuples(*[st.floats(allow_nan=True, allow_infinity=True, width=32)] * 2,
                           st.sampled_from([0.0, 0.0, 1.0])), max_size=6),
    kind=st.sampled_from(sorted(_VTK_TYPES)),
    ids=st.lists(st.lists(st.integers(-2, 8), min_size=1, max_size=5), max_size=4),
    suffix=st.sampled_from([".vtp", ".vtk", ".vtu"]),
)
def test_structurally_odd_vtk(tmp_path, pts, kind, ids, suffix):
    """Well-formed ASCII VTK files with odd content: no points, NaN points, point
    clouds, degenerate cells, cells referring to points that do not exist."""
    CASES["odd VTK content"] = CASES.get("odd VTK content", 0) + 1
    p = tmp_path / f"odd{suffix}"
    p.write_text(_vtk_text(suffix, pts, ids, kind))
    _check(p)




HUGE = {
    "huge.vtp": '<?xml version="1.0"?><VTKFile type="PolyData" version="0.1"><PolyData>'
                '<Piece NumberOfPoints="2000000000" NumberOfLines="1"><Points><DataArray '
                'type="Float64" NumberOfComponents="3" format="ascii">0 0 0 1 1 0</DataArray>'
                '</Points><Lines><DataArray type="Int64" Name="connectivity" format="ascii">0 1'
                '</DataArray><DataArray type="Int64" Name="offsets" format="ascii">2</DataArray>'
                "</Lines></Piece></PolyData></VTKFile>",
    "huge.vtk": "# vtk DataFile Version 3.0\nx\nBINARY\nDATASET POLYDATA\n"
                "POINTS 2000000000 float\n\0\0\0\0\0\0\0\0\nLINES 1 3\n",
    "hugecells.vtk": "# vtk DataFile Version 3.0\nx\nASCII\nDATASET POLYDATA\n"
                     "POINTS 2 float\n0 0 0 1 1 0\nLINES 1 3000000000\n2 0 1\n",
}


@pytest.mark.parametrize("name", sorted(HUGE))
def test_vtk_header_declaring_absurd_sizes_is_refused_quickly(tmp_path, name):
    """VTK allocates what a header declares: 2e9 points aborted the process
    (std::bad_alloc) for XML and took a minute for legacy binary files. Run in a
    child process so that a regression cannot take the test session down."""
    import subprocess
    import sys

    p = tmp_path / name
    p.write_bytes(HUGE[name].encode("latin-1"))
    code = ("from bayescalib.io.observations import read_interface, ObservationError\n"
            f"try:\n    read_interface({str(p)!r})\nexcept ObservationError as e:\n"
            "    print('REFUSED', e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert f"REFUSED {p}: the VTK header declares" in out.stdout
