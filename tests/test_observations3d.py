"""Observed 3D interfaces from a user's files (issue 40 item 2, in a study): surfaces
(STL, PLY, VTK polygons) and OCT volumes (a folder of B-scans, a NumPy array, a
multi-page TIFF) listed in ``observations.files`` are read, oriented and checked when
the study is read, before any solve: the voxel size and origin a volume needs, its size,
the units (the colony's extents against the 3D model's) and its placement (its mean
distance from the model's undeformed colony), each error naming the key and what to
write instead.

The colony here is the 3D smoke study's half-ellipsoid (semi-axes 0.3 x 0.4 x 0.3 mm,
centre (1, 0, 0.5) mm), voxelized at 10 um on a 50 um substrate slab."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from bayescalib.config import ConfigError, deep_merge, load_yaml, validate
from bayescalib.geometry.interface import Interface
from bayescalib.geometry.surface import enclosed_volume
from bayescalib.io.observation_store import read_observations
from bayescalib.io.observations import ObservationError, read_interface, write_interface_vtk
from bayescalib.io.volumes import MAX_VOLUME_VOXELS, is_volume, read_volume, volume_shape
from bayescalib.models.fsi.geometry3d import reference_surface
from bayescalib.stages.observe import observe
from bayescalib.study import Study

ROOT = Path(__file__).resolve().parents[1]
DEFAULT2D = load_yaml(ROOT / "config" / "config.yaml")
FSI3D = deep_merge(DEFAULT2D, load_yaml(ROOT / "config" / "fsi3d_smoke.yaml"))
GEOMETRY = validate(FSI3D["forward_model"]["fsi"], "fsi")["geometry"]
VOXEL = 0.01  # mm
ORIGIN = [0.5, -0.05, 0.1]  # mm: the centre of the first B-scan's bottom-left voxel
HALF_ELLIPSOID_VOLUME = 2.0 / 3.0 * np.pi * 0.3 * 0.4 * 0.3


def _mask() -> np.ndarray:
    """(nz, ny, nx) = (80, 61, 100): the colony on a 5-layer substrate slab."""
    xs = ORIGIN[0] + VOXEL * np.arange(100)
    ys = ORIGIN[1] + VOXEL * np.arange(61)
    zs = ORIGIN[2] + VOXEL * np.arange(80)
    Z, Y, X = np.meshgrid(zs, ys[::-1], xs, indexing="ij")  # row 0 at the top
    inside = ((X - 1.0) / 0.3) ** 2 + (Y / 0.4) ** 2 + ((Z - 0.5) / 0.3) ** 2 <= 1.0
    return inside | (Y < -0.001)


def _scan(mask: np.ndarray) -> np.ndarray:
    rng = np.random.default_rng(0)
    return np.clip(mask * 140.0 + 40.0 + rng.normal(0.0, 20.0, mask.shape), 0, 255
                   ).astype(np.uint8)


def _stl(path: Path, surface: Interface, scale: float = 1.0) -> Path:
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(surface.points * scale), deep=True))
    m = surface.cells.shape[0]
    cells = vtk.vtkCellArray()
    cells.SetData(numpy_to_vtkIdTypeArray(np.arange(0, 3 * m + 1, 3, dtype=np.int64), deep=True),
                  numpy_to_vtkIdTypeArray(np.ascontiguousarray(surface.cells.ravel()), deep=True))
    poly = vtk.vtkPolyData()
    poly.SetPoints(pts)
    poly.SetPolys(cells)
    w = vtk.vtkSTLWriter()
    w.SetFileName(str(path))
    w.SetInputData(poly)
    w.SetFileTypeToBinary()
    assert w.Write()
    return path


def _study(*entries):
    """The 3D smoke study on observation files (one entry per loading: two)."""
    files = [dict(e, load=load) for e, load in zip(entries, (50.0, 100.0))]
    return Study(deep_merge(FSI3D, {"observations": {"source": "files", "files": files}}))


def _volume(path, **extra):
    return {"path": str(path), "units": "mm", "pixel_size": [VOXEL] * 3,
            "origin": list(ORIGIN), "floor": 0.0, **extra}


def _volume_ok(surface: Interface, scan: bool) -> None:
    """A surface from the voxelized half-ellipsoid: in place, the right size, outward.

    Tolerances: marching cubes puts a mask's vertices within half a voxel of the
    boundary, the foot's chamfer onto the floor within about one (measured 0.89); a
    scan's Gaussian pre-filter (1.5 voxels) blurs the bright substrate into the colony's
    foot, which widens it by up to about two voxels there (measured 2.2), while the
    surface elsewhere stays within a voxel (99 % of the vertices)."""
    from bayescalib.geometry.projection import closest_points

    vol = enclosed_volume(surface.points, surface.cells, 0.0)
    assert vol == pytest.approx(HALF_ELLIPSOID_VOLUME, rel=0.03)  # positive: outward
    d = np.abs(closest_points(surface.points, reference_surface(GEOMETRY, n=48))[0])
    assert d.mean() < 0.25 * VOXEL
    assert np.quantile(d, 0.99) < (2.0 if scan else 1.0) * VOXEL
    assert d.max() < (3.0 if scan else 1.0) * VOXEL


# ----------------------------------------------------------------- volumes in a study
@pytest.fixture(scope="module")
def volumes(tmp_path_factory):
    """The same colony as a .npy mask, a multi-page TIFF scan and a folder of PNG
    B-scans."""
    import tifffile
    from skimage import io

    d = tmp_path_factory.mktemp("volumes")
    mask = _mask()
    np.save(d / "colony.npy", mask)
    scan = _scan(mask)
    tifffile.imwrite(d / "colony.tif", scan)
    (d / "bscans").mkdir()
    for k, b in enumerate(scan):
        io.imsave(d / "bscans" / f"b{k}.png", b, check_contrast=False)
    return d


@pytest.mark.parametrize("name", ["colony.npy", "colony.tif", "bscans"])
def test_a_volume_in_every_format_is_read_in_place_when_the_study_is_read(volumes, name):
    path = volumes / name
    assert is_volume(path) and volume_shape(path) == (80, 61, 100)
    study = _study(_volume(path), _volume(path))
    assert study.image_files == []  # a multi-page TIFF is a volume, not a B-scan figure
    paths = study.observation_paths
    assert len(paths) == (2 * 80 if name == "bscans" else 2)  # a folder: its B-scans
    _volume_ok(read_interface(path, **{k: v for k, v in _volume(path).items() if k != "path"}),
               scan=name != "colony.npy")


def test_the_observe_stage_stores_the_volumes_surfaces(volumes, tmp_path):
    entries = [_volume(volumes / "colony.npy"), _volume(volumes / "bscans")]
    section = validate({"observations": {"source": "files", "files": entries}},
                       "measures")["observations"]
    observe(section, tmp_path / "obs.h5")
    obs = read_observations(tmp_path / "obs.h5")
    assert [s.dim for s in obs.snapshots] == [3, 3] and obs.labels == ["colony", "bscans"]
    for s, scan in zip(obs.snapshots, (False, True)):
        _volume_ok(s, scan)


def test_a_volume_needs_three_voxel_sizes_and_a_3d_origin(volumes):
    path = volumes / "colony.npy"
    with pytest.raises(ConfigError, match=r"observations.files\[0\].pixel_size: .* is a volume, "
                       r"whose voxel size is three numbers \[dx, dy, dz\]"):
        _study(_volume(path, pixel_size=VOXEL), _volume(path))
    with pytest.raises(ConfigError, match=r"observations.files\[0\].origin: .* is a volume, "
                       r"whose origin is \[x, y, z\] in mm.*there is no default"):
        _study(_volume(path, origin=ORIGIN[:2]), _volume(path))
    # and a 2D image's settings are refused for a file that is not a volume
    surf = reference_surface(GEOMETRY)
    stl = _stl(volumes / "c.stl", surf)
    with pytest.raises(ConfigError, match=r"is not a volume .* pixel_size is one number"):
        _study({"path": str(stl), "pixel_size": [VOXEL] * 3}, {"path": str(stl)})


def test_a_volume_in_um_read_as_mm_is_refused_naming_the_unit_that_fits(volumes):
    path = volumes / "colony.npy"
    um = {"pixel_size": [10.0] * 3, "origin": [1e3 * v for v in ORIGIN], "floor": 0.0}
    with pytest.raises(ConfigError, match=r"observations.files\[0\] .* \d+ times as long "
                       r"\(x, along the flow\) .* the sizes agree if the file is in um"):
        _study(_volume(path, **um), _volume(path, **um))
    _study(_volume(path, units="um", **um), _volume(path, units="um", **um))  # in um: fine


def test_a_misplaced_volume_is_refused_with_the_origin_that_puts_it_in_place(volumes):
    path = volumes / "colony.npy"
    wrong = [ORIGIN[0], ORIGIN[1], ORIGIN[2] + 0.25]  # the colony 0.25 mm across the flow
    with pytest.raises(ConfigError) as err:
        _study(_volume(path, origin=wrong), _volume(path))
    msg = str(err.value)
    assert "observations.files[0]" in msg and "offset by about" in msg
    fixed = [float(v) for v in re.search(r"with origin \[([^\]]+)\] mm", msg).group(1).split(",")]
    np.testing.assert_allclose(fixed, ORIGIN, atol=VOXEL)  # within a voxel of the true one


def test_a_substrate_read_as_part_of_the_colony_is_named(volumes):
    with pytest.raises(ConfigError, match=r"touches the volume's border .* its lowest layer "
                       r"covers 100% of the B-scans' area: that is the substrate"):
        _study(_volume(volumes / "colony.npy", floor=-0.1), _volume(volumes / "colony.npy"))


def test_a_volume_with_two_colonies_lists_them_and_component_picks_one(tmp_path):
    two = _mask()
    two[30:40, 40:50, 5:15] = True  # a small second colony upstream
    np.save(tmp_path / "two.npy", two)
    entry = _volume(tmp_path / "two.npy")
    with pytest.raises(ConfigError, match=r"2 separate colonies .* #0: \d+ voxels .* #1: 1000 "
                       r"voxels .* pick one with component=k"):
        _study(entry, entry)
    _study(dict(entry, component=0), dict(entry, component=0))


def test_an_oversized_volume_is_refused_from_its_header_before_decoding(tmp_path):
    p = tmp_path / "big.npy"
    side = round(MAX_VOLUME_VOXELS ** (1 / 3)) + 10
    with open(p, "wb") as fh:  # the header only: reading the voxels would fail
        np.lib.format.write_array_header_1_0(
            fh, {"descr": "|u1", "fortran_order": False, "shape": (side, side, side)})
    assert volume_shape(p) == (side, side, side)
    with pytest.raises(ObservationError, match=r"big.npy: the volume is .* more than the limit "
                       r"of 100 million: refused before decoding"):
        read_volume(p)


# ----------------------------------------------------------------- surfaces in a study
def test_an_stl_in_um_with_inward_normals_is_read_in_mm_and_turned_outward(tmp_path):
    surf = reference_surface(GEOMETRY, n=16)
    flipped = Interface(surf.points, surf.cells[:, ::-1])
    stl = _stl(tmp_path / "colony.stl", flipped, scale=1e3)
    study = _study({"path": str(stl), "units": "um"}, {"path": str(stl), "units": "um"})
    assert study.observation_paths == [str(stl)] * 2
    back = read_interface(stl, units="um")
    assert enclosed_volume(back.points, back.cells, 0.0) == pytest.approx(
        enclosed_volume(surf.points, surf.cells, 0.0), rel=1e-6)  # outward, in mm
    with pytest.raises(ConfigError, match=r"1e\+03 times as long .* \(units: um\)"):
        _study({"path": str(stl)}, {"path": str(stl)})  # the default unit, mm


def test_a_vtk_surface_oriented_the_other_way_measures_as_the_right_one(tmp_path):
    """The RKHS currents are oriented: a file whose triangles turn the other way would be
    the opposite surface (about 750 times the noise's distance here) if taken as given."""
    from bayescalib.io.observations import add_noise
    from bayescalib.measures import rkhs

    surf = reference_surface(GEOMETRY, n=16)
    noisy = add_noise(surf, 0.001, np.random.default_rng(1))  # the rim is noisy too
    write_interface_vtk(tmp_path / "a.vtp", noisy)
    write_interface_vtk(tmp_path / "b.vtp", Interface(noisy.points, noisy.cells[:, ::-1]))
    a, b = read_interface(tmp_path / "a.vtp"), read_interface(tmp_path / "b.vtp")
    d_a, d_b = rkhs(surf, a, sigma_w=0.1).D, rkhs(surf, b, sigma_w=0.1).D
    assert d_b == pytest.approx(d_a, rel=1e-9)
    assert rkhs(surf, Interface(noisy.points, noisy.cells[:, ::-1]), sigma_w=0.1).D > 100 * d_a


def test_a_colony_cut_off_by_the_field_of_view_is_refused(tmp_path):
    surf = reference_surface(GEOMETRY, n=16)
    keep = surf.points[surf.cells].mean(axis=1)[:, 0] < 1.15  # the downstream part missing
    cut = Interface(surf.points, surf.cells[keep])
    write_interface_vtk(tmp_path / "cut.vtp", cut)
    with pytest.raises(ConfigError, match=r"observations.files\[0\]: .*rim vertices above the "
                       r"floor .* cut off"):
        _study({"path": str(tmp_path / "cut.vtp")}, {"path": str(tmp_path / "cut.vtp")})


def test_a_footprint_moved_sideways_is_refused_though_the_surface_lies_close(volumes):
    """A shift across the flow of a quarter of the footprint keeps the mean distance of the
    nodes under a quarter of the height; the base, attached, does not move under flow."""
    path = volumes / "colony.npy"
    wrong = [ORIGIN[0], ORIGIN[1], ORIGIN[2] + 0.15]
    with pytest.raises(ConfigError, match=r"its footprint's centre lies 0.1[45]\d* mm from "
                       r"the model's undeformed biofilm's"):
        _study(_volume(path, origin=wrong), _volume(path))


def test_the_model_colony_from_a_zero_flow_volume_and_observations_checked_against_it(volumes):
    """The field's practice in 3D: the unloaded volume is the model's geometry (a height
    field filled when the study is read), and the observed volumes are checked against
    that colony."""
    from bayescalib.models.fsi.scan3d import HeightField

    scan = _volume(volumes / "colony.npy")
    cfg = deep_merge(FSI3D, {"forward_model": {"fsi": {"geometry": {"shape": "scan",
                                                                     "scan": scan}}}})
    # the observed volumes: the same colony in another file (the zero-flow file itself
    # listed under flow is refused: test_the_zero_flow_volume_listed_as_a_loaded_...)
    files = [dict(_volume(volumes / "colony.tif"), load=load) for load in (50.0, 100.0)]
    study = Study(deep_merge(cfg, {"observations": {"source": "files", "files": files}}))
    assert any("as a height field" in n and "colony.npy" in n for n in study.notes)
    geometry = validate(study.config["forward_model"]["fsi"], "fsi")["geometry"]
    hf = HeightField.from_config(geometry["height_field"])
    assert hf.heights.max() == pytest.approx(0.4, abs=2 * VOXEL)
    ref = reference_surface(geometry)  # the colony the placement check compares with
    assert enclosed_volume(ref.points, ref.cells, 0.0) == pytest.approx(
        HALF_ELLIPSOID_VOLUME, rel=0.08)  # the height field's smoothing rounds the rim
    wrong = [ORIGIN[0] + 0.15, ORIGIN[1], ORIGIN[2]]
    files[0] = dict(files[0], origin=wrong)
    with pytest.raises(ConfigError, match=r"observations.files\[0\] .* footprint's centre"):
        Study(deep_merge(cfg, {"observations": {"source": "files", "files": files}}))
    with pytest.raises(ConfigError, match=r"geometry.scan: a 2D model's scan is an image"):
        Study(deep_merge(DEFAULT2D, {"forward_model": {"fsi": {"geometry": {
            "shape": "scan", "scan": scan}}}}))


def test_a_volume_with_its_axes_in_another_order_is_refused_naming_the_order(volumes, tmp_path):
    """A volume stored as en-face slices (ny, nz, nx) instead of B-scans (nz, ny, nx): the
    colony then reaches the top and sides of the 'volume'; the error says the axis order
    may be the cause, not only the field of view."""
    mask = np.load(volumes / "colony.npy")
    np.save(tmp_path / "en_face.npy", np.ascontiguousarray(mask.transpose(1, 0, 2)))
    entry = _volume(tmp_path / "en_face.npy")
    with pytest.raises(ConfigError, match=r"touches the volume's border .* axes are in another "
                       r"order than \(B-scan = z, row from the top = y, column = x\)"):
        _study(entry, entry)


def test_a_missing_volume_is_named_missing_whatever_its_settings(tmp_path):
    entry = _volume(tmp_path / "nowhere.npy")
    with pytest.raises(ConfigError, match=r"observations.files\[0\].path: .*nowhere.npy' does "
                       r"not exist"):
        _study(entry, entry)


def test_the_files_of_a_study_without_component_keep_their_validated_values():
    """component has no default: an existing study's observations.files entries validate
    to what they did, so its observe job (params: the observations section) does not
    rerun."""
    entry = validate({"observations": {"source": "files", "files": [{"path": "a.csv"}]}},
                     "measures")["observations"]["files"][0]
    assert "component" not in entry


def test_a_volume_whose_substrate_is_not_on_y0_is_refused_with_the_origin_that_fits(tmp_path):
    """The origin's y given as if the bottom row lay on the floor (the colony's foot is
    50 um above it; floor: auto finds it): an observed volume lifted so is within the
    placement check's quarter of the colony's height, and a model's colony from a volume
    with the same slip was taken with its rim 50 um up (the rim's tolerance grew with the
    floor found); both are refused when the study is read, with the origin that puts the
    substrate on y = 0, and an origin in another unit is named."""
    mask = _mask()
    mask[:, -5:, :] = False  # no substrate slab: the floor is the colony's foot
    path = tmp_path / "colony.npy"
    np.save(path, mask)
    lifted = _volume(path, origin=[ORIGIN[0], 0.0, ORIGIN[2]], floor="auto")
    with pytest.raises(ConfigError, match=r"observations.files\[0\] \(.*colony.npy'\): the floor "
                       r"found \(foreground bottom\) lies at y = 0.045 mm .* with origin "
                       r"\[0.5, -0.045, 0.1\] mm it would lie there"):
        _study(lifted, _volume(path, floor="auto"))
    _study(_volume(path, floor="auto"), _volume(path, floor="auto"))  # in place: fine

    def scan(entry):
        return Study(deep_merge(FSI3D, {"forward_model": {"fsi": {"geometry": {
            "shape": "scan", "scan": entry}}}}))

    with pytest.raises(ConfigError, match=r"geometry.scan \(.*colony.npy'\): the floor found "
                       r".* lies at y = 0.045 mm .* with origin \[0.5, -0.045, 0.1\] mm"):
        scan(lifted)
    in_um = _volume(path, origin=[1e3 * v for v in ORIGIN], floor="auto")  # units: mm
    with pytest.raises(ConfigError, match=r"or the origin is in um, not mm: origin "
                       r"\[0.5, -0.05, 0.1\] mm puts the substrate on y = 0"):
        scan(in_um)


def test_a_zero_flow_volume_in_another_unit_is_named_by_its_size(volumes):
    """A volume whose voxel size and origin are in mm under units: um (or in um under
    units: m) is a colony 1000 times too small (or large): refused naming its size
    against the channel and the unit that fits, not its rim's height."""
    entry = _volume(volumes / "colony.npy", units="um")  # the numbers are mm
    with pytest.raises(ConfigError, match=r"geometry.scan \(.*colony.npy'\): the colony "
                       r"\(0.000\d+ x .* mm in x, y, z\) is smaller than the mesh resolves "
                       r".*read as um: .* the sizes fit if they are in mm, units: mm"):
        Study(deep_merge(FSI3D, {"forward_model": {"fsi": {"geometry": {
            "shape": "scan", "scan": entry}}}}))


def test_the_zero_flow_volume_listed_as_a_loaded_observation_is_refused(volumes):
    """The model's colony from the zero-flow volume, and the same file listed again as the
    first snapshot (at factor 0.5): it lies where the model's colony is, so the placement
    and order checks pass, and the flow would seem not to have moved it (E pulled up).
    Refused naming the entry and its loading; at a factor 0 it is allowed."""
    scan = _volume(volumes / "colony.npy")
    cfg = deep_merge(FSI3D, {"forward_model": {"fsi": {"geometry": {"shape": "scan",
                                                                     "scan": scan}}}})
    files = [_volume(volumes / "colony.npy"), _volume(volumes / "colony.tif")]
    with pytest.raises(ConfigError, match=r"observations.files\[0\] \(.*colony.npy'\) is the "
                       r"model's zero-flow scan \(forward_model.fsi.geometry.scan.path\), "
                       r"observed here at loading factor 0.5"):
        Study(deep_merge(cfg, {"observations": {"source": "files", "files": files}}))
    zero = deep_merge(cfg, {"forward_model": {"loadings": {"factors": [0.0, 1.0]}}})
    Study(deep_merge(zero, {"observations": {"source": "files", "files": files}}))


def test_an_inverted_or_upside_down_volume_is_named_so(volumes, tmp_path):
    """Fluid bright and biofilm dark: the 'colony' was the fluid (its specks listed as
    separate colonies, with 'pick one with component=k'); B-scans upside down (row 0 the
    bottom): 'no foreground above the floor' alone. Each is named for what it is."""
    import tifffile

    scan = tifffile.imread(volumes / "colony.tif")
    tifffile.imwrite(tmp_path / "inverted.tif", (255 - scan).astype(np.uint8))
    entry = _volume(tmp_path / "inverted.tif", floor="auto")
    with pytest.raises(ConfigError, match=r"inverted.tif: the foreground .* fills 100 % of the "
                       r"volume's top layer .* looks like an inverted volume .* invert its grey "
                       r"values"):
        _study(entry, entry)
    from scipy.ndimage import gaussian_filter

    colony = _mask()
    colony[:, -5:, :] = False
    contrast = np.where(colony, 1.0, 0.0)
    contrast[:, -5:-2, :] = 2.5  # a substrate band brighter than the biofilm, dark below it
    grey = np.clip(40 + 70 * gaussian_filter(contrast, 1.0)
                   + np.random.default_rng(0).normal(0, 10, contrast.shape), 0, 255)
    upright = _volume(tmp_path / "upright.tif", floor="auto")
    tifffile.imwrite(upright["path"], grey.astype(np.uint8))
    _study(upright, upright)  # the band found below the colony, on y = 0
    tifffile.imwrite(tmp_path / "upside_down.tif",
                     np.ascontiguousarray(grey[:, ::-1, :]).astype(np.uint8))
    entry = _volume(tmp_path / "upside_down.tif", floor="auto")
    with pytest.raises(ConfigError, match=r"upside_down.tif: no foreground \(biofilm\) above the "
                       r"floor .* are they upside down \(row 0 must be the top"):
        _study(entry, entry)


def test_observed_voxel_sizes_are_checked_against_the_zero_flow_volumes(volumes):
    """The same three voxel sizes in another order than the zero-flow volume's is
    refused (before, the placement check named the origin, or, with both in the wrong
    order, nothing); another size is noted, as in 2D."""
    path = volumes / "colony.npy"

    def study(scan_size, obs_size):
        scan = _volume(path, pixel_size=scan_size)
        cfg = deep_merge(FSI3D, {"forward_model": {"fsi": {"geometry": {"shape": "scan",
                                                                         "scan": scan}}}})
        files = [dict(_volume(volumes / "colony.tif", pixel_size=obs_size), load=v)
                 for v in (50.0, 100.0)]
        return Study(deep_merge(cfg, {"observations": {"source": "files", "files": files}}))

    with pytest.raises(ConfigError, match=r"observations.files\[0\].pixel_size: \[10, 10, 12\] "
                       r"um, the zero-flow volume's voxel size \(forward_model.fsi.geometry.scan"
                       r".pixel_size: \[12, 10, 10\] um\) in another order: both are \[dx, dy, "
                       r"dz\]"):
        study([0.012, VOXEL, VOXEL], [VOXEL, VOXEL, 0.012])
    notes = study([VOXEL] * 3, [0.0105, VOXEL, VOXEL]).notes
    assert any("pixel_size: observations.files[0] [10.5, 10, 10] um" in n and "the model's "
               "zero-flow volume (forward_model.fsi.geometry.scan) has [10, 10, 10] um voxels"
               in n for n in notes)


def _leaning(shear: float) -> np.ndarray:
    """The colony of :func:`_mask` bent along x: its top ``shear`` mm downstream."""
    xs = ORIGIN[0] + VOXEL * np.arange(100)
    ys = ORIGIN[1] + VOXEL * np.arange(61)
    zs = ORIGIN[2] + VOXEL * np.arange(80)
    Z, Y, X = np.meshgrid(zs, ys[::-1], xs, indexing="ij")
    inside = (((X - 1.0 - shear * np.clip(Y, 0, None) / 0.4) / 0.3) ** 2 + (Y / 0.4) ** 2
              + ((Z - 0.5) / 0.3) ** 2 <= 1.0)
    return inside | (Y < -0.001)


def test_colonies_bent_upstream_or_listed_in_reverse_order_are_refused(volumes, tmp_path):
    """The model's colony from the zero-flow volume; the observed colonies bent 20 and 40 um
    downstream at factors 0.5 and 1 are accepted. Mirrored in x (B-scan columns against
    the flow) they lean upstream, which the placement check lets through: refused. Listed
    in the reverse order they are refused by their lean (in 3D the mean distance from the
    model's colony is blurred by the geometry's own misfit)."""
    for name, shear in (("a", 0.02), ("b", 0.04), ("ma", -0.02), ("mb", -0.04)):
        np.save(tmp_path / f"{name}.npy", _leaning(shear))
    scan = _volume(volumes / "colony.npy")
    cfg = deep_merge(FSI3D, {"forward_model": {"fsi": {"geometry": {"shape": "scan",
                                                                     "scan": scan}}}})

    def study(*names):
        files = [_volume(tmp_path / f"{n}.npy") for n in names]
        return Study(deep_merge(cfg, {"observations": {"source": "files", "files": files}}))

    study("a", "b")
    with pytest.raises(ConfigError, match=r"the observed colonies lean upstream of the model's "
                       r"undeformed biofilm \(observations.files\[0\] -\d+.* um, .* are the "
                       r"B-scans' columns running against the flow \(x mirrored\)\?"):
        study("ma", "mb")
    with pytest.raises(ConfigError, match=r"lean the farther downstream of the model's "
                       r"undeformed biofilm the smaller their loading .* reverse order"):
        study("b", "a")


def test_volumes_with_x_and_z_swapped_are_refused_by_their_bend_across_the_flow(tmp_path):
    """Every volume stored (nx, ny, nz), the zero-flow one included: the model's colony
    is swapped as the observed ones are, so the size and placement checks pass, and the
    observed colonies bend across the model's flow. Refused naming the axes."""
    def swapped(mask):
        return np.ascontiguousarray(mask.transpose(2, 1, 0))

    np.save(tmp_path / "zero.npy", swapped(_leaning(0.0)))
    for name, shear in (("a", 0.02), ("b", 0.04)):
        np.save(tmp_path / f"{name}.npy", swapped(_leaning(shear)))
    origin = [ORIGIN[0], ORIGIN[1], 0.0]  # the colony mid-channel across the flow
    scan = _volume(tmp_path / "zero.npy", origin=origin)
    cfg = deep_merge(FSI3D, {"forward_model": {"fsi": {"geometry": {"shape": "scan",
                                                                     "scan": scan}}}})
    files = [_volume(tmp_path / f"{n}.npy", origin=origin) for n in ("a", "b")]
    with pytest.raises(ConfigError, match=r"the observed colonies bend across the flow \(z\), "
                       r"not along it .* are the volumes' x and z axes swapped"):
        Study(deep_merge(cfg, {"observations": {"source": "files", "files": files}}))



def test_a_colony_moved_as_a_whole_is_not_taken_for_a_bent_one(volumes, tmp_path):
    """The lean is measured against the colony's base: observed volumes moved 30 um
    upstream as a whole (cropped with the origin kept: within the placement check's 10 %
    of the footprint) do not lean upstream."""
    moved = np.roll(_mask(), -3, axis=2)
    for name in ("a", "b"):
        np.save(tmp_path / f"{name}.npy", moved)
    scan = _volume(volumes / "colony.npy")
    cfg = deep_merge(FSI3D, {"forward_model": {"fsi": {"geometry": {"shape": "scan",
                                                                     "scan": scan}}}})
    files = [_volume(tmp_path / f"{n}.npy") for n in ("a", "b")]
    Study(deep_merge(cfg, {"observations": {"source": "files", "files": files}}))


def test_a_folder_volume_must_be_one_numbered_series_of_bscans(volumes, tmp_path):
    """An extra image of the B-scans' size (a copy, an en-face view) or a missing B-scan
    moved every B-scan after it by one spacing without a word; both are refused naming
    the names or numbers. Evenly numbered files (by their z in um) are fine."""
    import shutil

    from skimage import io

    files = sorted((volumes / "bscans").iterdir(), key=lambda f: int(f.stem[1:]))
    extra, gap, even = (tmp_path / n for n in ("extra", "gap", "even"))
    for d in (extra, gap, even):
        d.mkdir()
    for k, f in enumerate(files):
        shutil.copy(f, extra / f.name)
        if k != 40:
            shutil.copy(f, gap / f.name)
        shutil.copy(f, even / f"z{100 + 10 * k:04d}um.png")
    io.imsave(extra / "b1_copy.png", io.imread(files[1]), check_contrast=False)
    with pytest.raises(ObservationError, match=r"extra: the folder's images are not one numbered "
                       r"series of B-scans: 80 named 'b#.png', and 'b#_copy.png' \(1: "
                       r"'b1_copy.png'\)"):
        volume_shape(extra)
    with pytest.raises(ObservationError, match=r"gap: B-scans missing from the numbered series 0 "
                       r"to 79: 40 \(1\)"):
        volume_shape(gap)
    assert volume_shape(even) == (80, 61, 100)


def test_the_fields_section_of_a_scanned_colony_is_its_footprints_middle(volumes):
    """The workflow's fields figure cuts a 3D model at the colony's mid-plane; with the
    colony from a zero-flow volume that raised 'a 2D slice of geometry.shape scan is not
    defined' when the Snakefile was parsed, so no such study could run (snakemake -n
    failed). It is the middle of the footprint's z-range."""
    from bayescalib.models.fsi.slice2d import midplane_z

    scan = _volume(volumes / "colony.npy")
    study = Study(deep_merge(FSI3D, {"forward_model": {"fsi": {"geometry": {
        "shape": "scan", "scan": scan}}}}))
    z = midplane_z(study.config["forward_model"]["fsi"]["geometry"])
    assert z == pytest.approx(0.5, abs=2 * VOXEL)


def test_without_a_substrate_band_the_floor_is_under_the_foot_not_under_its_blur():
    """No substrate band: the floor is the bottom of the foreground. A sparse layer below
    the colony's foot (blur or speckle: 22 voxels under a foot of 5800 in the example
    recording without its band) put it a layer too low, and the foot's underside stayed
    in the surface (half the footprint's area facing down: an 'overhang' for the model's
    colony, a second sheet for an observation)."""
    from bayescalib.geometry.volume import volume_surface

    mask = _mask()
    mask[:, -5:, :] = False  # no substrate
    rng = np.random.default_rng(0)
    k, c = rng.integers(30, 50, 30), rng.integers(40, 60, 30)
    mask[k, -5, c] = True  # a few voxels of blur under the foot
    surf, info = volume_surface(mask, voxel_size=[VOXEL] * 3, units="mm", origin=ORIGIN,
                                floor="auto")
    assert info["floor"]["method"] == "foreground bottom"
    assert info["floor"]["y_mm"] == pytest.approx(-0.5 * VOXEL)  # under the foot (y = 0)
    down = surf.normals[:, 1] < -0.5
    assert surf.measures[down].sum() < 0.02 * surf.measures.sum()


def test_a_component_that_picks_another_colony_is_named_in_the_placement_error(volumes,
                                                                               tmp_path):
    """component ranks a volume's colonies by size; under flow (or in another volume) the
    ranks may change, and the colony picked is then the wrong one: the placement error
    says so besides the origin."""
    xs = ORIGIN[0] + VOXEL * np.arange(200)
    ys = ORIGIN[1] + VOXEL * np.arange(61)
    zs = ORIGIN[2] + VOXEL * np.arange(80)
    Z, Y, X = np.meshgrid(zs, ys[::-1], xs, indexing="ij")
    colony = ((X - 1.0) / 0.3) ** 2 + (Y / 0.4) ** 2 + ((Z - 0.5) / 0.3) ** 2 <= 1.0
    bigger = ((X - 1.9) / 0.31) ** 2 + (Y / 0.4) ** 2 + ((Z - 0.5) / 0.3) ** 2 <= 1.0
    np.save(tmp_path / "two.npy", colony | bigger | (Y < -0.001))
    scan = _volume(volumes / "colony.npy")
    cfg = deep_merge(FSI3D, {"forward_model": {"fsi": {"geometry": {"shape": "scan",
                                                                     "scan": scan}}}})
    files = [_volume(tmp_path / "two.npy", component=0), _volume(volumes / "colony.tif")]
    with pytest.raises(ConfigError, match=r"observations.files\[0\] .* footprint's centre .* "
                       r"or observations.files\[0\].component picked another colony: the "
                       r"volume holds 2, ranked by size"):
        Study(deep_merge(cfg, {"observations": {"source": "files", "files": files}}))
