"""Synthetic OCT recordings of a biofilm colony in a flow cell.

A recording is what a user of the calibration brings: B-scans of one colony taken
at a few flow rates, the first without flow, with the pixel size and position of the
images. Here it is made from the forward model itself, so that the truth is known:

1. an analytic colony (:mod:`bayescalib.geometry.shapes`) is the reference shape;
2. the fsi model is solved on it at the true parameters, with a hidden effect the
   calibrated model lacks, at the inflow loadings ``factors x nominal`` by continuation
   (the library's series solve, :func:`bayescalib.models.forward.solve_series`, as the
   ground-truth solve of a study; ``examples/oct_colony/make_recording.py`` does it:
   this module, in the geometry layer, does not import the models), on a finer mesh
   than a study uses;
3. every deformed interface (upstream foot to downstream foot, closed along the floor)
   is drawn into one image grid (:func:`scan_grid`) as an OCT-like B-scan
   (:func:`render_recording_scan`): the biofilm above the floor ``y = 0`` and the bright
   flow-cell floor (the substrate) as a band of ``substrate_thickness`` below it, each
   as area-fraction occupancy blurred by a Gaussian point-spread function
   (:func:`bayescalib.geometry.imaging.render_scan`), then multiplied by gamma speckle
   and added Gaussian noise (the model of ``render_scan``):

   ``I = (G * a_biofilm + c_s G * a_substrate) S + noise N``,

   with fluid 0, biofilm 1 and substrate ``c_s`` in mean;
4. the intensities are stored as 16-bit PNG counts ``(I + INTENSITY_OFFSET) *
   COUNTS_PER_CONTRAST`` (clipped to [0, 65535]) with a ``recording.json`` that says
   how to read them (pixel size and the position of the centre of the bottom-left
   pixel in um, the convention of :mod:`bayescalib.geometry.imaging`), and the
   noiseless model interfaces as CSV (um) for checks.

Every random number comes from one :class:`numpy.random.Generator` seeded by the
caller, used scan after scan in order: the same inputs give the same files.

The image grid has its pixel edges on multiples of the pixel size, so the floor
``y = 0`` is a pixel edge: the ``rows_below_floor`` bottom rows are the substrate and
what lies below it, the rows above are fluid and biofilm.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.geometry.imaging import render_scan

__all__ = [
    "COUNTS_PER_CONTRAST",
    "INTENSITY_OFFSET",
    "ScanSettings",
    "decode_counts",
    "encode_counts",
    "read_recording",
    "render_recording_scan",
    "scan_grid",
    "write_recording",
]

#: PNG counts per unit of biofilm-fluid contrast
COUNTS_PER_CONTRAST = 8000.0
#: intensity added before encoding, so that the fluid (mean 0, with noise) stays >= 0
INTENSITY_OFFSET = 1.0


@dataclass(frozen=True)
class ScanSettings:
    """How the B-scans are taken.

    Attributes
    ----------
    pixel_size : float
        mm (0.004 = 4 um).
    margin : float
        Fluid around the colony on the left, right and top, mm.
    substrate_thickness : float
        Bright band below the floor (the flow-cell bottom), mm; a multiple of the
        pixel size.
    below_substrate : float
        Dark rows below the band, mm; a multiple of the pixel size.
    substrate_intensity : float
        Mean intensity of the band, in units of the biofilm-fluid contrast.
    psf_sigma : float
        Point-spread function, pixels.
    looks : float
        Speckle looks (intensity sd ``1/sqrt(looks)`` of the mean).
    noise : float
        Additive noise sd, in units of the contrast.
    supersample : int
        Sub-samples per pixel and axis of the occupancy.
    """

    pixel_size: float = 0.004
    margin: float = 0.08
    substrate_thickness: float = 0.02
    below_substrate: float = 0.012
    substrate_intensity: float = 1.6
    psf_sigma: float = 1.0
    looks: float = 4.0
    noise: float = 0.05
    supersample: int = 8

    def rows(self, length: float) -> int:
        """``length`` (mm) in whole pixels (it must be one, to 1e-9)."""
        k = length / self.pixel_size
        if abs(k - round(k)) > 1e-9:
            raise ValueError(f"{length} mm is not a whole number of {self.pixel_size} mm pixels")
        return round(k)

    @property
    def rows_below_floor(self) -> int:
        """Image rows below the floor ``y = 0`` (substrate and below)."""
        return self.rows(self.substrate_thickness) + self.rows(self.below_substrate)


def scan_grid(bounds: np.ndarray,
              settings: ScanSettings) -> tuple[tuple[int, int], tuple[float, float]]:
    """Image grid covering ``bounds`` with the margin, the floor on a pixel edge.

    Parameters
    ----------
    bounds : array_like, shape (2, 2)
        ``[[xmin, ymin], [xmax, ymax]]`` of everything to be seen (all snapshots), mm.
    settings : ScanSettings

    Returns
    -------
    shape : (int, int)
        ``(H, W)`` pixels.
    origin : (float, float)
        Centre of the bottom-left pixel, mm; ``x`` and ``y`` are half a pixel off a
        multiple of the pixel size.
    """
    b = np.asarray(bounds, dtype=float)
    s = settings.pixel_size
    c0 = int(np.floor((b[0, 0] - settings.margin) / s))
    c1 = int(np.ceil((b[1, 0] + settings.margin) / s))
    top = int(np.ceil((b[1, 1] + settings.margin) / s))
    below = settings.rows_below_floor
    return (top + below, c1 - c0), ((c0 + 0.5) * s, (-below + 0.5) * s)


def render_recording_scan(
    interface: np.ndarray,
    *,
    shape: tuple[int, int],
    origin: tuple[float, float],
    settings: ScanSettings,
    rng: np.random.Generator,
) -> np.ndarray:
    """OCT-like B-scan of a colony on the flow-cell floor (see the module docstring).

    Parameters
    ----------
    interface : array_like, shape (n, 2)
        The fluid-biofilm interface from the upstream foot to the downstream foot
        (the biofilm on its right, as the fsi model orders it), feet on ``y = 0``, mm.
    shape, origin
        From :func:`scan_grid`.
    settings : ScanSettings
    rng : numpy.random.Generator
        Source of the speckle and the noise.

    Returns
    -------
    ndarray of float, shape (H, W)
        Intensity, fluid 0, biofilm 1, substrate ``settings.substrate_intensity`` in
        mean; row 0 is the top.
    """
    pts = np.asarray(interface, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 3:
        raise ValueError(f"interface must be an (n >= 3, 2) array in mm, got shape {pts.shape}")
    if pts[0, 0] >= pts[-1, 0]:
        raise ValueError("interface must run from the upstream (left) foot to the downstream foot")
    s = settings.pixel_size
    _, w = shape
    x_lo, x_hi = origin[0] - 2 * s, origin[0] + (w + 1) * s
    t = settings.substrate_thickness
    band = np.array([[x_lo, -t], [x_lo, 0.0], [x_hi, 0.0], [x_hi, -t]])  # clockwise
    clean = {"pixel_size": s, "origin": origin, "shape": shape,
             "psf_sigma": settings.psf_sigma, "looks": None, "noise": 0.0,
             "supersample": settings.supersample, "rng": rng}
    img = render_scan(pts, **clean) + settings.substrate_intensity * render_scan(band, **clean)
    if settings.looks is not None:
        img = img * rng.gamma(float(settings.looks), 1.0 / float(settings.looks), size=img.shape)
    if settings.noise > 0:
        img = img + float(settings.noise) * rng.standard_normal(img.shape)
    return img


def encode_counts(image: np.ndarray) -> np.ndarray:
    """Intensity -> 16-bit counts ``round((I + INTENSITY_OFFSET) * COUNTS_PER_CONTRAST)``,
    clipped to [0, 65535] (intensities -1 to 7.19)."""
    c = np.rint((np.asarray(image, dtype=float) + INTENSITY_OFFSET) * COUNTS_PER_CONTRAST)
    return np.clip(c, 0, 65535).astype(np.uint16)


def decode_counts(counts: np.ndarray) -> np.ndarray:
    """16-bit counts -> intensity (the inverse of :func:`encode_counts` up to rounding)."""
    return np.asarray(counts, dtype=float) / COUNTS_PER_CONTRAST - INTENSITY_OFFSET


def _csv(path: Path, points_um: np.ndarray) -> None:
    with path.open("w") as fh:
        fh.write("x,y\n")
        for x, y in points_um:
            fh.write(f"{x:.4f},{y:.4f}\n")


def write_recording(
    out: str | Path,
    interfaces: Sequence[np.ndarray],
    factors: Sequence[float],
    *,
    nominal: float,
    settings: ScanSettings,
    seed: int,
    metadata: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Render and write a recording: ``scan_<k>.png``, ``truth_<k>.csv``, ``recording.json``.

    Parameters
    ----------
    out : path
        Folder (created).
    interfaces : sequence of (n_k, 2) arrays
        The deformed interfaces, upstream to downstream foot, mm, one per loading.
    factors : sequence of float
        Loading factors, one per interface (the file number ``k`` is the position).
    nominal : float
        Nominal inflow rate, mm^2/s.
    settings : ScanSettings
    seed : int
        Seed of the speckle and noise generator.
    metadata : mapping, optional
        Merged into ``recording.json`` (truth, hidden effect, colony, mesh, ...).

    Returns
    -------
    dict
        The content of ``recording.json``.
    """
    from PIL import Image

    if len(interfaces) != len(factors):
        raise ValueError("one interface per loading factor is needed")
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    allpts = np.vstack([np.asarray(p, dtype=float) for p in interfaces])
    bounds = np.array([allpts.min(axis=0), allpts.max(axis=0)])
    shape, origin = scan_grid(bounds, settings)
    rng = np.random.default_rng(seed)
    scans = []
    for k, (pts, f) in enumerate(zip(interfaces, factors, strict=True)):
        img = render_recording_scan(pts, shape=shape, origin=origin, settings=settings, rng=rng)
        name = f"scan_{k}.png"
        Image.fromarray(encode_counts(img)).save(folder / name, optimize=True)
        _csv(folder / f"truth_{k}.csv", 1000.0 * np.asarray(pts, dtype=float))
        scans.append({"file": name, "loading_factor": float(f),
                      "inflow_rate_mm2_per_s": float(f) * float(nominal),
                      "truth_interface": f"truth_{k}.csv"})
    um = 1000.0
    record: dict[str, Any] = {
        "format": "bayescalib synthetic OCT recording 1",
        "units": "um",
        "pixel_size": settings.pixel_size * um,
        "origin": [origin[0] * um, origin[1] * um],
        "origin_is": "centre of the bottom-left pixel; x downstream, y up; image row 0 is the top",
        "image_shape": [int(shape[0]), int(shape[1])],
        "floor": {"y": 0.0, "rows_below": settings.rows_below_floor,
                  "substrate_rows": settings.rows(settings.substrate_thickness),
                  "note": "y = 0 is the edge between image rows H-1-rows_below and H-rows_below; "
                          "the substrate band lies just below it"},
        "intensity": {"counts_per_contrast": COUNTS_PER_CONTRAST, "offset": INTENSITY_OFFSET,
                      "decode": "I = counts / counts_per_contrast - offset (fluid 0, biofilm 1)",
                      "substrate": settings.substrate_intensity},
        "render": {k: v for k, v in asdict(settings).items()},
        "render_units": "pixel_size, margin, substrate_thickness, below_substrate in mm; "
                        "psf_sigma in pixels; noise in units of the contrast",
        "noise_seed": int(seed),
        "inflow_nominal_mm2_per_s": float(nominal),
        "scans": scans,
        "truth_interfaces": "truth_<k>.csv: the noiseless model interface (mesh vertices, "
                            "upstream to downstream foot), x,y in um",
        **dict(metadata or {}),
    }
    (folder / "recording.json").write_text(json.dumps(record, indent=1) + "\n")
    return record


def read_recording(folder: str | Path) -> tuple[dict[str, Any], list[np.ndarray]]:
    """``recording.json`` and the scans as intensity images (float, row 0 the top)."""
    from PIL import Image

    folder = Path(folder)
    record = json.loads((folder / "recording.json").read_text())
    images = [decode_counts(np.asarray(Image.open(folder / s["file"]))) for s in record["scans"]]
    return record, images
