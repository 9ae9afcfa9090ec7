"""The model's undeformed biofilm from a recording (geometry.shape: scan).

Specification: a colony traced from a scan keeps its area and interface length
within a pixel; the order and orientation a tracer gives do not matter; with
several colonies the user's choice (or the largest) is taken and said; what cannot
be meshed or is misplaced is refused when the study is read, naming the key and
the fix; the extracted shape meshes and solves.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bayescalib.config import ConfigError, validate
from bayescalib.geometry import outline as ol
from bayescalib.geometry.imaging import pixel_grid, render_mask
from bayescalib.geometry.interface import Interface
from bayescalib.geometry.shapes import ellipse_patch, lobed_colony
from bayescalib.io.colony import read_colony
from bayescalib.io.observations import ObservationError, write_interface_csv, write_mask_png
from bayescalib.study import Study

S = 0.004  # pixel size, mm (4 um, an OCT B-scan's)


def _arc_colony(r_of_t, centre=1.0, n=4000):
    """Interface x = c + r(t) cos t, y = r(t) sin t, t from pi to 0 (foot to foot)."""
    t = np.linspace(np.pi, 0.0, n)
    r = r_of_t(t)
    return np.column_stack([centre + r * np.cos(t), r * np.sin(t)])


def _ellipse(a, b):
    return ellipse_patch(1.0, a, b).interface(4000)


def _mask_file(tmp_path, curves, name="scan.png", margin=0.05):
    """A noiseless mask (area fraction > 1/2) of one or more colonies on the image's
    bottom edge (the floor y = 0); returns the scan entry."""
    pts = np.vstack(curves)
    shape, origin = pixel_grid(np.array([pts.min(axis=0), pts.max(axis=0)]), S, margin=margin,
                               floor=0.0)
    mask = np.zeros(shape, dtype=bool)
    for c in curves:
        mask |= render_mask(c, pixel_size=S, origin=origin, shape=shape,
                            rng=np.random.default_rng(0), psf_sigma=0.0, looks=None, noise=0.0,
                            smooth=0.0, threshold=0.5, min_size=0)
    path = tmp_path / name
    write_mask_png(path, mask, pixel_size=S, origin=origin)
    return {"path": str(path), "units": "mm", "pixel_size": S, "origin": list(origin)}


def _read(scan):
    """read_colony on a geometry.scan section validated by the fsi schema (defaults in)."""
    geo = validate({"geometry": {"shape": "scan", "scan": scan}}, "fsi")["geometry"]
    return read_colony(geo["scan"])


LOBED = lambda t: 0.28 * (1 + 0.12 * np.cos(3 * t + 0.5))


@pytest.mark.parametrize("colony", [
    ellipse_patch(1.0, 0.25, 0.25),          # semicircle
    ellipse_patch(1.0, 0.2, 0.4),            # tall
    ellipse_patch(1.0, 0.35, 0.2),           # wide
    lobed_colony(width=0.8, height=0.38, seed=0),   # the example's: lobes and an overhang
    lobed_colony(width=0.7, height=0.3, centre=0.95, seed=2),
], ids=["semicircle", "tall", "wide", "lobed0", "lobed2"])
def test_a_traced_colony_keeps_its_area_and_interface_length_within_a_pixel(tmp_path, colony):
    """Exact area and interface length by quadrature of the analytic curve
    (bayescalib.geometry.shapes). Tolerances: interface length within one pixel (the
    staircase of the raw trace adds 6-8 pixels; the default smoothing of two pixels
    removes it), area within a band of half a pixel along the interface (the trace is
    sub-pixel accurate)."""
    traced = _read(_mask_file(tmp_path, [colony.interface(4000)]))
    assert abs(traced.info["length_mm"] - colony.perimeter) <= S, \
        (traced.info["length_mm"], colony.perimeter)
    assert abs(traced.info["area_mm2"] - colony.area) <= 0.5 * colony.perimeter * S
    assert traced.info["smoothing_mm"] == pytest.approx(2 * S)
    p = traced.interface
    assert p[0, 0] < p[-1, 0] and p[0, 1] == pytest.approx(0.0) and p[-1, 1] == pytest.approx(0.0)


def test_the_order_and_orientation_of_an_outline_file_do_not_matter(tmp_path):
    curve = _arc_colony(LOBED, n=300)
    floor = np.array([[curve[-1, 0], -0.02], [curve[0, 0], -0.02]])
    closed = np.vstack([curve, floor])  # clockwise: over the top, back under the floor
    got = []
    for k, pts in enumerate([closed, closed[::-1], np.roll(closed, 37, axis=0)]):
        path = tmp_path / f"outline{k}.csv"
        write_interface_csv(path, Interface.polyline(pts, closed=True))
        got.append(_read({"path": str(path)}).interface)
    for k, pts in enumerate([curve, curve[::-1]]):  # an open interface, either direction
        path = tmp_path / f"open{k}.csv"
        write_interface_csv(path, Interface.polyline(pts))
        got.append(_read({"path": str(path)}).interface)
    for g in got[1:]:
        assert g.shape == got[0].shape and np.allclose(g, got[0], atol=1e-9)
    assert got[0][0, 0] < got[0][-1, 0]


def test_polygon_orientation_is_normalized():
    sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    assert ol.signed_area(sq) == pytest.approx(1.0)
    assert ol.signed_area(ol.counterclockwise(sq[::-1])) == pytest.approx(1.0)
    assert ol.counterclockwise(np.vstack([sq, sq[:1]])).shape == (4, 2)


def test_with_two_colonies_the_largest_or_the_named_one_is_modelled(tmp_path):
    big = _ellipse(0.2, 0.3)
    small = np.column_stack([1.55 + 0.1 * np.cos(np.linspace(np.pi, 0, 400)),
                             0.12 * np.sin(np.linspace(np.pi, 0, 400))])
    entry = _mask_file(tmp_path, [big, small])
    colony = _read(entry)
    assert colony.info["n_colonies"] == 2 and "largest" in colony.info["colony"]
    assert colony.interface[:, 0].max() < 1.25
    picked = _read({**entry, "colony": [1.4, 1.7]})
    assert picked.interface[:, 0].min() > 1.4 and "x-range" in picked.info["colony"]
    with pytest.raises(ObservationError, match="no colony lies in the given x-range"):
        _read({**entry, "colony": [0.1, 0.2]})


def test_a_colony_cut_by_the_image_border_is_refused(tmp_path):
    entry = _mask_file(tmp_path, [_ellipse(0.25, 0.3)], margin=0.0)
    with pytest.raises(ObservationError, match="(left|right).*border.*field of view"):
        _read(entry)


def test_a_substrate_away_from_the_floor_is_refused_with_the_origin_that_fits(tmp_path):
    entry = _mask_file(tmp_path, [_ellipse(0.25, 0.3)])
    wrong = {**entry, "origin": [entry["origin"][0], entry["origin"][1] + 0.1]}
    with pytest.raises(ObservationError) as exc:
        _read(wrong)
    msg = str(exc.value)
    assert "geometry.scan" in msg and "y = 0.1" in msg
    assert f"{entry['origin'][1]:.6g}" in msg  # the origin that puts the substrate at y = 0
    with pytest.raises(ObservationError, match="origin is required"):
        _read({k: v for k, v in entry.items() if k != "origin"})


def test_outlines_the_mesh_cannot_resolve_are_refused():
    """Gaps narrower than two interface elements (min_gap) cannot be meshed."""
    ok = ol.resample_curve(_ellipse(0.3, 0.4), 0.005)
    ol.validate_colony(ok, channel_length=2.0, channel_height=1.0, min_gap=0.07)
    # a mushroom: its cap overhangs the floor with a 30 um fluid gap under it
    mushroom = ol.resample_curve(np.array([
        [0.9, 0.0], [0.9, 0.03], [0.6, 0.03], [0.55, 0.1], [0.7, 0.3], [1.0, 0.35],
        [1.3, 0.3], [1.45, 0.1], [1.4, 0.03], [1.1, 0.03], [1.1, 0.0]]), 0.005)
    # a crevice 20 um wide and 0.2 mm deep between two lobes
    pinched = ol.resample_curve(np.array([
        [0.7, 0.0], [0.7, 0.3], [0.99, 0.3], [0.99, 0.1], [1.01, 0.1], [1.01, 0.3],
        [1.3, 0.3], [1.3, 0.0]]), 0.005)
    for bad, words in [
        (mushroom, "overhang.*fluid gap"),
        (pinched, "nearly touches itself"),
        (ol.resample_curve(_ellipse(0.3, 0.4) + [0.8, 0.0], 0.005), "outside the channel"),
        (ol.resample_curve(_ellipse(0.3, 1.2), 0.005), "channel top"),
    ]:
        with pytest.raises(ol.OutlineError, match=words):
            ol.validate_colony(bad, channel_length=2.0, channel_height=1.0, min_gap=0.07)


def _scan_study(entry, tmp_path, files=None, **geometry):
    cfg = {
        "study": "scan_geometry", "results_dir": str(tmp_path / "results"),
        "parameters": [
            {"name": "E", "unit": "Pa", "target": "material.E",
             "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0}},
            {"name": "nu", "unit": "-", "target": "material.nu",
             "prior": {"type": "uniform", "lo": -0.5, "hi": 0.45}},
        ],
        "forward_model": {"type": "fsi", "fsi": {
            "geometry": {"shape": "scan", **({"scan": entry} if entry else {}), **geometry},
            "mesh": {"preset": "coarse"}}},
        "observations": {"source": "files", "files": files or []},
    }
    return Study(cfg, where="mine.yaml")


def test_a_scan_study_meshes_the_scanned_colony_and_checks_observations_against_it(tmp_path):
    curve = _arc_colony(LOBED)
    entry = _mask_file(tmp_path, [curve])
    obs = tmp_path / "loaded.csv"
    write_interface_csv(obs, Interface.polyline(curve[::40] + [0.0, 0.0]))
    study = _scan_study(entry, tmp_path, files=[{"path": str(obs)}])
    geo = study.config["forward_model"]["fsi"]["geometry"]
    assert len(geo["outline"]) > 50 and any("colony of" in n for n in study.notes)
    # the same recording 0.5 mm off (an origin left out) is refused, naming the offset
    off = tmp_path / "off.csv"
    write_interface_csv(off, Interface.polyline(curve[::40] - [0.5, 0.0]))
    with pytest.raises(ConfigError) as exc:
        _scan_study(entry, tmp_path, files=[{"path": str(off)}])
    assert "observations.files[0].origin" in str(exc.value) and "(-0.501, +0.000)" in str(exc.value)
    # in um read as mm: refused as a scale mismatch naming the unit that fits
    um = tmp_path / "um.csv"
    write_interface_csv(um, Interface.polyline(curve[::40] * 1000.0))
    with pytest.raises(ConfigError, match=r"observations.files\[0\].units.*in um"):
        _scan_study(entry, tmp_path, files=[{"path": str(um)}])
    with pytest.raises(ConfigError, match=r"geometry.scan is required"):
        _scan_study(None, tmp_path, files=[{"path": str(obs)}])


def test_the_half_ellipse_study_refuses_an_image_placed_half_a_millimetre_off(tmp_path):
    """The trial that found it: a mask of the default colony with its origin left out."""
    entry = _mask_file(tmp_path, [_ellipse(0.3, 0.4)])
    cfg_files = [{"path": entry["path"], "pixel_size": S, "origin": [0.0, 0.0]}]
    cfg = {
        "study": "misplaced", "results_dir": str(tmp_path / "results"),
        "parameters": [{"name": "E", "unit": "Pa", "target": "material.E",
                        "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0}}],
        "observations": {"source": "files", "files": cfg_files},
    }
    with pytest.raises(ConfigError, match=r"observations.files\[0\].*offset by about \(-0.65"):
        Study(cfg)
    cfg["observations"]["files"][0]["origin"] = entry["origin"]
    Study(cfg)


def test_the_mesh_of_a_scanned_colony_follows_it_and_solves(tmp_path):
    from bayescalib.models.fsi.model import FSIModel

    curve = _arc_colony(LOBED)
    entry = _mask_file(tmp_path, [curve])
    colony = _read(entry)
    model = FSIModel({"geometry": {"shape": "scan", "scan": entry}, "mesh": {"preset": "coarse"}})
    result = model.solve({"material.E": 400.0, "material.nu": 0.3})
    assert result.status == "ok", result.reason
    ref = Interface.polyline(colony.interface)
    from bayescalib.geometry.projection import closest_points

    d, _, _ = closest_points(result.interface_reference, ref)
    assert np.max(np.abs(d)) < 0.25 * S  # the mesh's interface nodes lie on the traced one
    assert result.interface_reference[0, 0] == pytest.approx(colony.interface[0, 0], abs=S)


def test_the_example_scan_gives_back_its_colony():
    """The example's zero-flow B-scan (16-bit, 4 um pixels, 4-look speckle, a bright
    substrate band; examples/oct_colony/README.md) read as the model's geometry:
    the substrate's surface is found at y = 0 within half a pixel and the traced
    colony lies within a pixel (RMS) of the noiseless interface it was rendered from,
    its length within a pixel and its area within half a pixel band."""
    from bayescalib.geometry.projection import closest_points

    ex = Path(__file__).resolve().parents[1] / "examples" / "oct_colony"
    rec = json.loads((ex / "recording.json").read_text())
    scan = {"path": str(ex / "scan_0.png"), "units": rec["units"],
            "pixel_size": rec["pixel_size"], "origin": rec["origin"], "floor": "auto"}
    colony = _read(scan)
    s = rec["pixel_size"] * 1e-3
    assert abs(colony.info["floor_mm"]) <= 0.5 * s
    truth = np.loadtxt(ex / "truth_0.csv", delimiter=",", skiprows=1) * 1e-3
    d, _, _ = closest_points(colony.interface, Interface.polyline(truth))
    assert np.sqrt(np.mean(d**2)) <= s
    length, area = rec["colony"]["interface_length_mm"], rec["colony"]["area_mm2"]
    assert abs(colony.info["length_mm"] - length) <= s
    assert abs(colony.info["area_mm2"] - area) <= 0.5 * length * s


def test_a_typed_outline_solves_in_either_orientation():
    """The trial that found it: a half-ellipse outline listed clockwise stopped the solve
    with "OCC-Triangulation could not be built"; outlines are now made counterclockwise."""
    from bayescalib.models.fsi.model import FSIModel

    ccw = ellipse_patch(1.0, 0.3, 0.4).outline(60)
    refs = []
    for outline in (ccw, ccw[::-1]):
        model = FSIModel({"geometry": {"shape": "polyline", "outline": outline.tolist()},
                          "mesh": {"preset": "coarse"}})
        result = model.solve({"material.E": 400.0, "material.nu": 0.3})
        assert result.status == "ok", result.reason
        refs.append(result.interface_current)
    assert refs[0].shape == refs[1].shape and np.allclose(refs[0], refs[1], atol=1e-9)


# ------------------------------------------------- a user's own recording (new-user probe)
OCT = Path(__file__).resolve().parents[1] / "examples" / "oct_colony"


def _oct_entry(path, **change):
    """The OCT example's zero-flow scan entry (um, 4 um pixels), for another file."""
    return {"path": str(path), "units": "um", "pixel_size": 4.0, "origin": [522.0, -30.0],
            "floor": "auto", **change}


def _oct_pixels(i=0):
    from PIL import Image

    return np.array(Image.open(OCT / f"scan_{i}.png"))


def test_a_jpeg_scan_is_refused_as_an_unsupported_file_not_for_its_floor(tmp_path):
    """A .jpg zero-flow scan with floor: auto was refused with "floor: 'auto' applies to
    images", though it is an image: the file type is what is wrong."""
    from PIL import Image

    path = tmp_path / "scan_0.jpg"
    Image.fromarray((_oct_pixels() >> 8).astype(np.uint8)).save(path)
    with pytest.raises(ObservationError, match="not a supported file") as exc:
        _read(_oct_entry(path))
    assert "applies to images" not in str(exc.value) and ".png" in str(exc.value)


def test_a_multi_page_tiff_is_refused_as_a_2d_models_scan(tmp_path):
    """A 3-page TIFF (an OCT volume) given to the 2D model was read as an RGB image (its
    pages taken for colour channels) and its first page modelled, silently."""
    import tifffile

    img = _oct_pixels()
    tifffile.imwrite(tmp_path / "one.tif", img)
    tifffile.imwrite(tmp_path / "stack.tif", np.stack([img] * 3), photometric="minisblack")
    assert _read(_oct_entry(tmp_path / "one.tif")).info["n_colonies"] == 1  # one page: fine
    with pytest.raises(ObservationError, match="multi-page TIFF") as exc:
        _read(_oct_entry(tmp_path / "stack.tif"))
    assert "geometry.dim: 3" in str(exc.value)


def test_an_inverted_scan_is_refused_as_inverted_not_as_misplaced(tmp_path):
    """The example's zero-flow scan with its grey values inverted (fluid bright) was
    refused with an origin "that would put the substrate at y = 0": the wrong fix."""
    from PIL import Image

    path = tmp_path / "inv.png"
    Image.fromarray((65535 - _oct_pixels().astype(np.int64)).astype(np.uint16)).save(path)
    with pytest.raises(ObservationError, match="inverted image") as exc:
        _read(_oct_entry(path))
    assert "origin" not in str(exc.value)
    assert str(exc.value).count(str(path)) == 1  # the path said once


@pytest.mark.parametrize("change, hint", [
    ({"units": "mm", "pixel_size": 0.004}, "origin is in um, not mm: origin [0.522, -0.03] mm"),
    ({"pixel_size": 0.004}, "pixel_size is in mm, not um: pixel_size 4 um"),
])
def test_a_floor_off_by_a_unit_slip_names_the_unit(change, hint):
    """An origin copied in um under units: mm (or a pixel size in mm under um) puts the
    substrate far from y = 0; the message gave an origin fixing only y, in a sentence
    that ended "it would be"."""
    with pytest.raises(ObservationError) as exc:
        _read(_oct_entry(OCT / "scan_0.png", **change))
    msg = str(exc.value)
    assert "it would lie there" in msg and hint in msg, msg


def test_a_scan_without_floor_auto_is_told_of_floor_auto():
    """floor left out (null: the image's bottom edge) on a scan whose substrate band lies
    8 rows above it: the origin offered moves the band into the colony; floor: auto is
    named as the other fix."""
    entry = _oct_entry(OCT / "scan_0.png")
    entry.pop("floor")
    with pytest.raises(ObservationError, match="give floor: auto") as exc:
        _read(entry)
    assert "pixel_size is in" not in str(exc.value)  # no spurious unit hint
