"""Synthetic OCT recordings (bayescalib.geometry.recording, examples/oct_colony): the
rendering must be reproducible from its seed, the floor must lie on a pixel edge at
the row recording.json names, and a scan segmented as an analysis pipeline would
(imaging.segment_scan, imaging.mask_contour) must give back the colony within about a
pixel: area within one pixel layer along the interface (perimeter x pixel size),
every point within 2 pixels of the true outline, and the interface length within 1 %
once the contour is taken every 4 pixels (the raw marching-squares contour of a
speckled mask is rough at the pixel scale: 5-7 % too long). The
committed example must read back as recording.json describes it. The data solve
itself (fine mesh, four loadings, about a minute) is a slow test."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bayescalib.geometry.imaging import mask_contour, segment_scan
from bayescalib.geometry.interface import Interface
from bayescalib.geometry.outline import curve_length, signed_area
from bayescalib.geometry.recording import (
    ScanSettings,
    decode_counts,
    encode_counts,
    read_recording,
    render_recording_scan,
    scan_grid,
    write_recording,
)
from bayescalib.geometry.shapes import lobed_colony

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "oct_colony"
SETTINGS = ScanSettings()  # 4 um pixels, 4-look speckle, PSF 1 pixel, noise 0.05


def _closed_on_floor(curve: np.ndarray) -> np.ndarray:
    """An open interface (upstream to downstream foot) closed along the floor y = 0."""
    return np.vstack([[curve[0, 0], 0.0], curve, [curve[-1, 0], 0.0]])


def _segment(image: np.ndarray, origin, s: float) -> np.ndarray:
    """The interface of a scan: smoothed threshold at half the contrast, contour above
    the floor, upstream foot first. The bright substrate is segmented with the biofilm,
    and the noisy top edge of its band wanders up to about a pixel above y = 0: the
    contour is cut 1.5 pixels above the floor (``floor = s``), which leaves out the
    last 1.5 pixels of the interface at each foot."""
    mask = segment_scan(image, smooth=1.0, threshold=0.5, min_size=16)
    pts = np.asarray(mask_contour(mask, s, origin, floor=s).points)
    return pts if pts[0, 0] < pts[-1, 0] else pts[::-1]


def _every(curve: np.ndarray, spacing: float) -> np.ndarray:
    """The curve taken at equal arc-length steps of about ``spacing`` (mm), ends kept."""
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(curve, axis=0).T))])
    q = np.linspace(0.0, arc[-1], int(np.ceil(arc[-1] / spacing)) + 1)
    return np.column_stack([np.interp(q, arc, curve[:, 0]), np.interp(q, arc, curve[:, 1])])


def test_render_is_reproducible_from_its_seed():
    c = lobed_colony(seed=0)
    shape, origin = scan_grid(np.array([[0.6, 0.0], [1.4, 0.38]]), SETTINGS)

    def scan(seed):
        return render_recording_scan(c.interface(200), shape=shape, origin=origin,
                                     settings=SETTINGS, rng=np.random.default_rng(seed))

    np.testing.assert_array_equal(scan(3), scan(3))
    assert not np.array_equal(scan(3), scan(4))


def test_floor_is_a_pixel_edge_and_the_grid_covers_the_colony():
    """The bottom rows_below_floor rows lie below y = 0, the row above them starts at it;
    the margin of fluid is there on the left, right and top."""
    b = np.array([[0.6013, 0.0], [1.3987, 0.3812]])
    (h, w), (x0, y0) = scan_grid(b, SETTINGS)
    s = SETTINGS.pixel_size
    k = SETTINGS.rows_below_floor
    assert k == 8  # 20 um substrate + 12 um below, 4 um pixels
    assert y0 + (k - 0.5) * s == pytest.approx(0.0, abs=1e-12)  # bottom edge of row H-1-k
    assert x0 - 0.5 * s <= b[0, 0] - SETTINGS.margin
    assert x0 + (w - 0.5) * s >= b[1, 0] + SETTINGS.margin
    assert y0 + (h - 0.5) * s >= b[1, 1] + SETTINGS.margin


def test_counts_encode_and_decode():
    img = np.array([[-1.2, -0.5, 0.0], [1.0, 1.6, 8.0]])
    c = encode_counts(img)
    assert c.dtype == np.uint16
    np.testing.assert_allclose(decode_counts(c), np.clip(img, -1.0, 65535 / 8000 - 1), atol=1e-4)


def test_zero_flow_scan_gives_back_the_colony_within_a_pixel(tmp_path):
    """Render -> 16-bit PNG -> read -> segment -> contour, for the example colony at rest.
    Measured (4 um pixels, noise seeds 1-5): area off by < 0.07 pixel layers, points
    within 1.7 pixels (rms 0.4), length every 4 pixels within 0.6 %, raw +5-7 %."""
    c = lobed_colony(seed=0)
    rec = write_recording(tmp_path, [c.interface(200)], [0.0], nominal=100.0,
                          settings=SETTINGS, seed=1)
    back, (image,) = read_recording(tmp_path)
    assert back == json.loads(json.dumps(rec))
    s = back["pixel_size"] / 1000.0  # the files are in um
    origin = np.asarray(back["origin"]) / 1000.0
    assert image.shape == tuple(back["image_shape"])
    # the substrate band: the rows just below the floor are bright across the image (its
    # edge rows are blurred by the point-spread function)
    sub = back["floor"]["substrate_rows"]
    band = image[image.shape[0] - back["floor"]["rows_below"]:][1:sub - 1]
    assert band.mean() == pytest.approx(SETTINGS.substrate_intensity, rel=0.1)
    curve = _segment(image, origin, s)
    area = signed_area(_closed_on_floor(curve)[::-1])
    assert abs(area - c.area) <= c.perimeter * s, (area, c.area)
    assert curve_length(_every(curve, 4 * s)) == pytest.approx(c.perimeter, rel=0.01)
    assert c.perimeter < curve_length(curve) < 1.08 * c.perimeter
    truth = Interface.polyline(c.interface(800))
    dist = _distance_to(truth, curve)
    assert dist.max() <= 2 * s, dist.max() / s


def _distance_to(curve: Interface, points: np.ndarray) -> np.ndarray:
    """Distance (mm) of each point to a polyline."""
    p = np.asarray(curve.points)
    a, b = p[:-1], p[1:]
    ab = b - a
    t = np.einsum("mij,ij->mi", points[:, None, :] - a[None], ab) / np.sum(ab * ab, 1)
    t = np.clip(t, 0.0, 1.0)
    foot = a[None] + t[..., None] * ab[None]
    return np.min(np.linalg.norm(points[:, None, :] - foot, axis=2), axis=1)


@pytest.mark.skipif(not (EXAMPLE / "recording.json").is_file(), reason="example not generated")
def test_committed_example_reads_back_as_described():
    """The committed scans: four 16-bit PNGs on one grid, the truth in um, and each scan's
    segmented interface within 2 pixels of its truth_<k>.csv (the zero-flow one is the
    colony at rest: the truth of the model's reference mesh)."""
    rec, images = read_recording(EXAMPLE)
    assert rec["units"] == "um"
    assert [s["loading_factor"] for s in rec["scans"]] == [0.0, 0.5, 1.0, 1.5]
    s = rec["pixel_size"] / 1000.0
    origin = np.asarray(rec["origin"]) / 1000.0
    for scan, image in zip(rec["scans"], images, strict=True):
        assert image.shape == tuple(rec["image_shape"])
        truth = np.loadtxt(EXAMPLE / scan["truth_interface"], delimiter=",", skiprows=1) / 1000.0
        curve = _segment(image, origin, s)
        assert _distance_to(Interface.polyline(truth), curve).max() <= 2 * s
    size = sum(f.stat().st_size for f in EXAMPLE.iterdir() if f.is_file())
    assert size < 600_000


@pytest.mark.slow
def test_generator_is_deterministic_end_to_end(tmp_path):
    """The script twice with the same seeds: byte-identical scans and truth files, and the
    same recording.json but for the command line (which names the output folder); one
    data solve each, fine mesh, about 25 s each on one core."""
    import runpy
    import sys

    script = EXAMPLE / "make_recording.py"
    for k in (1, 2):
        argv = sys.argv
        sys.argv = [str(script), "--out", str(tmp_path / f"r{k}")]
        try:
            runpy.run_path(str(script), run_name="__main__")
        finally:
            sys.argv = argv
    for f in sorted((tmp_path / "r1").iterdir()):
        if f.name == "recording.json":
            one, two = (json.loads((tmp_path / r / f.name).read_text()) for r in ("r1", "r2"))
            assert one.pop("command") != two.pop("command")
            assert one == two
        else:
            assert f.read_bytes() == (tmp_path / "r2" / f.name).read_bytes(), f.name
