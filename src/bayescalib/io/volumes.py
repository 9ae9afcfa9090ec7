"""OCT volumes from files: the observed colony's surface of a 3D recording.

A volume is one of

* a NumPy array file ``.npy`` of shape ``(nz, ny, nx)`` (a stack of ``nz`` B-scans,
  each ``ny`` rows from the top by ``nx`` columns), any numeric or boolean type;
* a multi-page TIFF (``.tif``/``.tiff`` of more than one page: one B-scan per page,
  the way OCT software exports a volume); a one-page TIFF is a 2D image (a B-scan);
* a folder of 2D images (``.png``/``.tif``/``.tiff``), one B-scan per file, taken in
  the natural order of their names (``scan2`` before ``scan10``); the names must be one
  numbered series (alike but for their numbers, none missing: another image or a gap
  would move the B-scans after it by a spacing).

The axes and coordinates are those of :mod:`bayescalib.geometry.volume`: B-scan ``k``
is the plane ``z = z0 + k dz``, its row 0 the top. The size is checked from the
header (the ``.npy`` header, the TIFF pages, the first image of a folder) before any
voxel is decoded: more than :data:`MAX_VOLUME_VOXELS` is refused (crop or bin the
volume), so that a wrong file costs no memory. The surface is then
:func:`bayescalib.geometry.volume.volume_surface`'s (segmentation, floor, one colony,
marching cubes, Taubin smoothing); about 2 s for a 400 x 200 x 300 volume on one core
(measured on a synthetic half-ellipsoid scan, 2026-11-27), which the study pays when
it is read (every check is made before any solve).

Every failure is an :class:`bayescalib.io.observations.ObservationError` naming the file
and the value.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.geometry.interface import Interface
from bayescalib.geometry.surface import SurfaceError
from bayescalib.io.observations import IMAGE_SUFFIXES, VOLUME_SUFFIXES, ObservationError

__all__ = ["FLOOR_TOL_MM", "MAX_VOLUME_VOXELS", "VOLUME_SUFFIXES", "is_volume", "read_volume",
           "read_volume_surface", "substrate_offset", "volume_files", "volume_shape",
           "write_volume_recording"]

#: largest volume decoded, voxels (about 0.8 GB as float64; the segmentation holds a few
#: such arrays)
MAX_VOLUME_VOXELS = 100_000_000
_TIFF = {".tif", ".tiff"}
#: a volume's substrate found this far from y = 0 (mm; and at least two voxels in y) is a
#: misplaced volume (the 2D zero-flow scan's rule, :data:`bayescalib.io.colony.FLOOR_TOL_MM`)
FLOOR_TOL_MM = 0.01


def _natural(name: str) -> list[Any]:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def _slices(folder: Path) -> list[Path]:
    files = [f for f in folder.iterdir()
             if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES and not f.name.startswith(".")]
    return sorted(files, key=lambda f: _natural(f.name))


def _series(files: Sequence[Path], where: str) -> None:
    """A folder volume's images are one numbered series of B-scans: their names alike but
    for their numbers, and (with one varying number) none missing. Another image (a copy,
    an en-face view of the same size) or a missing B-scan would move every B-scan after it
    by one spacing (B-scan k is the k-th in name order, at ``z0 + k dz``) without a word.

    Raises
    ------
    ObservationError
        Naming the odd names, or the missing numbers."""
    groups: dict[str, list[str]] = {}
    for f in files:
        groups.setdefault(re.sub(r"\d+", "#", f.name), []).append(f.name)
    if len(groups) > 1:
        main = max(groups, key=lambda k: len(groups[k]))
        odd = "; ".join(f"'{k}' ({len(v)}: {', '.join(repr(n) for n in v[:3])}"
                        + (", ..." if len(v) > 3 else "") + ")"
                        for k, v in groups.items() if k != main)
        raise ObservationError(
            f"{where}: the folder's images are not one numbered series of B-scans: "
            f"{len(groups[main])} named '{main}', and {odd}: a folder volume holds its "
            "B-scans only (the k-th in natural name order at z0 + k dz); move the others out")
    names = next(iter(groups.values()))
    numbers = [[int(t) for t in re.findall(r"\d+", n)] for n in names]
    varying = [i for i in range(len(numbers[0])) if len({row[i] for row in numbers}) > 1]
    if len(varying) != 1:
        return
    k = sorted(row[varying[0]] for row in numbers)
    steps = np.diff(k)
    if len(set(steps.tolist())) <= 1:  # evenly numbered (e.g. by their z in um)
        return
    step = int(np.bincount(steps).argmax())  # the usual step
    gaps = sorted(set(range(k[0], k[-1] + 1, step)) - set(k)) if step > 0 else []
    if gaps and len(gaps) < len(k):
        shown = ", ".join(str(v) for v in gaps[:10]) + (", ..." if len(gaps) > 10 else "")
        raise ObservationError(
            f"{where}: B-scans missing from the numbered series {k[0]} to {k[-1]}: {shown} "
            f"({len(gaps)}): the volume puts the k-th B-scan in name order at z0 + k dz, so "
            "every one after a gap would lie a spacing off; restore them (or number the "
            "files evenly, as they lie)")


def _tiff_pages(path: Path) -> tuple[int, tuple[int, ...]] | None:
    """Number of pages and the first page's shape of a TIFF, from its header (None when
    tifffile cannot read it: the 2D image reader then says why)."""
    try:
        import tifffile

        with tifffile.TiffFile(path) as tf:
            series = tf.series[0] if tf.series else None
            if series is not None and len(series.shape) >= 3 and series.shape[-1] > 4:
                return int(np.prod(series.shape[:-2])), tuple(int(v) for v in series.shape[-2:])
            return len(tf.pages), tuple(int(v) for v in tf.pages[0].shape)
    except Exception:  # noqa: BLE001 - not a readable TIFF: the 2D reader reports it
        return None


def volume_files(path: str | Path) -> list[Path]:
    """The files a path's interface is read from: a folder volume's B-scans (natural
    order), else the path itself."""
    p = Path(path)
    return _slices(p) if p.is_dir() else [p]


def is_volume(path: str | Path) -> bool:
    """Whether an observation path is a volume (module docstring): a folder, a ``.npy``
    file, or a TIFF of more than one page."""
    p = Path(path)
    if p.is_dir():
        return True
    suffix = p.suffix.lower()
    if suffix in VOLUME_SUFFIXES:
        return True
    if suffix in _TIFF and p.is_file():
        pages = _tiff_pages(p)
        return pages is not None and pages[0] > 1
    return False


def volume_shape(path: str | Path) -> tuple[int, int, int]:
    """``(nz, ny, nx)`` of a volume from its header(s), without decoding the voxels.

    Raises
    ------
    ObservationError
        Not a volume, an unreadable header, a folder without images, B-scans of
        different sizes (a folder's first and last), an array that is not 3D.
    """
    from bayescalib.geometry.imaging import ImageError, image_size

    p = Path(path)
    where = str(p)
    if p.is_dir():
        files = _slices(p)
        if len(files) < 2:
            raise ObservationError(
                f"{where}: a folder volume needs at least 2 B-scan images "
                f"({', '.join(sorted(IMAGE_SUFFIXES))}), found {len(files)}")
        _series(files, where)
        try:
            (w0, h0), (w1, h1) = image_size(files[0]), image_size(files[-1])
        except ImageError as exc:
            raise ObservationError(str(exc)) from None
        if (w0, h0) != (w1, h1):
            raise ObservationError(f"{where}: the B-scans differ in size: '{files[0].name}' is "
                                   f"{w0} x {h0}, '{files[-1].name}' {w1} x {h1} pixels")
        return len(files), h0, w0
    suffix = p.suffix.lower()
    if suffix == ".npy":
        try:
            with open(p, "rb") as fh:
                version = np.lib.format.read_magic(fh)
                read = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                        else np.lib.format.read_array_header_2_0)
                shape, _, _ = read(fh)
        except (ValueError, OSError) as exc:
            raise ObservationError(f"{where}: not a NumPy array file ({exc})") from None
        if len(shape) != 3:
            raise ObservationError(f"{where}: a volume is an array (nz, ny, nx) of B-scans, "
                                   f"got shape {tuple(shape)}")
        return tuple(int(v) for v in shape)  # type: ignore[return-value]
    if suffix in _TIFF:
        pages = _tiff_pages(p)
        if pages is None or pages[0] < 2:
            raise ObservationError(f"{where}: not a multi-page TIFF volume")
        if len(pages[1]) != 2:
            raise ObservationError(f"{where}: the TIFF's pages are of shape {pages[1]}, not "
                                   "greyscale B-scans (rows, columns)")
        return pages[0], pages[1][0], pages[1][1]
    raise ObservationError(f"{where}: not a volume (a folder of B-scans, a .npy array or a "
                           "multi-page TIFF)")


def read_volume(path: str | Path, max_voxels: int = MAX_VOLUME_VOXELS
                ) -> tuple[np.ndarray, dict[str, Any]]:
    """The voxels of a volume file (module docstring), after the header's size check.

    Returns
    -------
    volume : ndarray, shape (nz, ny, nx)
        Grey values (or a mask) in the file's own scale.
    info : dict
        ``shape`` [nz, ny, nx], ``format`` (``"npy"``, ``"tiff"``, ``"folder"``),
        ``dtype``; ``files`` (the B-scans' names) for a folder.
    """
    from bayescalib.geometry.imaging import ImageError, read_image

    p = Path(path)
    where = str(p)
    nz, ny, nx = volume_shape(p)
    if nz * ny * nx > int(max_voxels):
        raise ObservationError(
            f"{where}: the volume is {nx} x {ny} x {nz} voxels ({nz * ny * nx / 1e6:.0f} "
            f"million), more than the limit of {int(max_voxels) / 1e6:g} million: refused "
            "before decoding (crop the region of the colony, or bin the voxels and give "
            "the binned pixel_size)")
    info: dict[str, Any] = {"shape": [nz, ny, nx]}
    if p.is_dir():
        files = _slices(p)
        scans = []
        for f in files:
            try:
                img, _ = read_image(f)
            except ImageError as exc:
                raise ObservationError(str(exc)) from None
            if img.shape != (ny, nx):
                raise ObservationError(f"{where}: the B-scan '{f.name}' is {img.shape[1]} x "
                                       f"{img.shape[0]} pixels, the first {nx} x {ny}")
            scans.append(img)
        vol = np.stack(scans)
        info.update(format="folder", files=[f.name for f in files], dtype=str(vol.dtype))
        return vol, info
    try:
        if p.suffix.lower() == ".npy":
            vol = np.load(p, allow_pickle=False)
            info["format"] = "npy"
        else:
            import tifffile

            vol = np.asarray(tifffile.imread(p))
            info["format"] = "tiff"
    except Exception as exc:  # noqa: BLE001 - decoders raise anything on a broken file
        raise ObservationError(f"{where}: cannot read the volume ({type(exc).__name__}: "
                               f"{exc})") from None
    vol = vol.reshape(nz, ny, nx) if vol.size == nz * ny * nx else vol
    if vol.shape != (nz, ny, nx):
        raise ObservationError(f"{where}: read an array of shape {vol.shape}, the header "
                               f"says {(nz, ny, nx)}")
    if not (vol.dtype == bool or np.issubdtype(vol.dtype, np.number)):
        raise ObservationError(f"{where}: unsupported voxel type {vol.dtype}")
    info["dtype"] = str(vol.dtype)
    return vol, info


def read_volume_surface(
    path: str | Path,
    *,
    units: str,
    pixel_size: float | Sequence[float] | None,
    origin: Sequence[float] | None,
    image: str = "auto",
    segmentation: Mapping[str, Any] | None = None,
    floor: float | str | None = "auto",
    component: int | None = None,
) -> tuple[Interface, dict[str, Any]]:
    """The colony's surface in a volume file, in mm (module docstring).

    Parameters
    ----------
    path : str or Path
        A volume (:func:`is_volume`).
    units : {"mm", "um", "m"}
        Unit of ``pixel_size``, ``origin`` and a numeric ``floor``.
    pixel_size : (float, float, float)
        Voxel size ``(dx, dy, dz)``: along the B-scan's columns (x, the flow), its rows
        (y, depth) and between B-scans (z). Three numbers, required: OCT voxels are rarely
        cubic (the axial size differs from the lateral ones).
    origin : (float, float, float)
        Position of the centre of voxel ``[0, ny - 1, 0]`` (the bottom-left pixel of the
        first B-scan).
    image : {"auto", "mask", "scan"}
    segmentation : mapping, optional
        Scan settings (``smooth``, ``threshold``, ``min_size``; voxels).
    floor : "auto", float or None
        The substrate plane (:func:`bayescalib.geometry.volume.volume_surface`).
    component : int, optional
        Which colony when the volume holds several (0 = the largest).

    Returns
    -------
    surface : Interface
        Vertices ``(n, 3)`` and triangles ``(m, 3)``, mm, normals into the fluid.
    info : dict
        ``kind`` ``"volume"``, the file's (:func:`read_volume`) and the surface's
        (:func:`bayescalib.geometry.volume.volume_surface`), whose ``kind`` (``"mask"``
        or ``"scan"``) is ``image`` here.
    """
    from bayescalib.geometry.volume import volume_surface

    where = str(path)
    size = np.atleast_1d(np.asarray(pixel_size if pixel_size is not None else [], dtype=float))
    if size.shape != (3,):
        raise ObservationError(
            f"{where}: a volume needs pixel_size [dx, dy, dz] (three numbers, in {units}: "
            "along the B-scan's columns, its rows and between B-scans), got "
            f"{pixel_size!r}: OCT voxels are rarely cubic, so there is no one-number form")
    if origin is None or len(origin) != 3:
        raise ObservationError(
            f"{where}: a volume needs origin [x, y, z] (in {units}): the position of the "
            f"centre of the first B-scan's bottom-left pixel, got {origin!r}")
    vol, vinfo = read_volume(path)
    try:
        surf, sinfo = volume_surface(vol, voxel_size=size, units=units, origin=origin,
                                     kind=image, segmentation=segmentation, floor=floor,
                                     component=component, name=where)
    except SurfaceError as exc:
        raise ObservationError(str(exc)) from None
    return surf, {**vinfo, **sinfo, "image": sinfo["kind"], "kind": "volume"}


def substrate_offset(info: Mapping[str, Any], *, units: str, pixel_size: Sequence[float],
                     origin: Sequence[float]) -> str | None:
    """Why a volume's substrate is not on the flow cell's floor y = 0, or None.

    The substrate's surface is the floor the reading found (``floor: auto``): a bright
    band's own top edge (below the plane the surface is cut at, on top of the band's
    blurred halo), else the floor itself. More than :data:`FLOOR_TOL_MM` (and two voxels)
    from y = 0 is a wrong ``origin`` (its y: e.g. the bottom row put at y = 0 though the
    substrate lies above it, or the top row's y given), or a unit slip of the origin or
    the voxel size, which the checks of size and placement let through when the model's
    colony comes from a volume with the same slip: the colony would sit on a ledge or
    reach far up into the channel. A floor given as a number is the user's plane: None.

    Parameters
    ----------
    info : mapping
        The reading record of :func:`read_volume_surface`.
    units, pixel_size, origin
        As given (for the values that fit, in the same units).

    Returns
    -------
    str or None
        The reason with the origin that puts the substrate on y = 0 (and, where the
        origin or the voxel size alone in another unit does, that unit), without the
        file's name.
    """
    from bayescalib.geometry.surface import UNITS

    fl = info.get("floor") or {}
    if fl.get("method") == "given" or fl.get("y_mm") is None:
        return None
    band = fl.get("edge_y_mm") is not None
    y_sub = float(fl["edge_y_mm"] if band else fl["y_mm"])
    vox = [float(v) for v in info["voxel_size_mm"]]
    tol = max(FLOOR_TOL_MM, 2.0 * vox[1])
    if abs(y_sub) <= tol:
        return None
    f = UNITS[units]
    y0 = float(info["origin_mm"][1])
    fixed = ", ".join(f"{v:.6g}" for v in (origin[0], (y0 - y_sub) / f, origin[2]))
    slip = ""
    for u, g in UNITS.items():  # the origin first: its numbers are copied from another tool
        if u != units and abs(y_sub - y0 + y0 * g / f) <= tol:
            o = ", ".join(f"{v * g / f:.6g}" for v in origin)
            slip = (f"; or the origin is in {u}, not {units}: origin [{o}] {units} puts the "
                    "substrate on y = 0")
            break
    else:
        for u, g in UNITS.items():
            if u != units and abs(y0 + (y_sub - y0) * g / f) <= max(FLOOR_TOL_MM,
                                                                    2.0 * vox[1] * min(1, g / f)):
                s = ", ".join(f"{v * g / f:.6g}" for v in pixel_size)
                slip = (f"; or pixel_size is in {u}, not {units}: pixel_size [{s}] {units} "
                        "puts the substrate on y = 0")
                break
    what = ("the substrate's surface (the top edge of the bright band found below the "
            "colony)" if band else f"the floor found ({fl['method']})")
    return (f"{what} lies at y = {y_sub:.4g} mm in the volume's coordinates (origin "
            f"{[float(v) for v in origin]} {units}), but the flow cell's floor is y = 0 "
            f"(tolerance {tol * 1e3:.3g} um): with origin [{fixed}] {units} it would lie there "
            "(origin is the centre of the first B-scan's bottom-left pixel)" + slip)


def write_volume_recording(
    out: str | Path,
    surfaces: Sequence[Interface],
    factors: Sequence[float],
    *,
    nominal: float,
    settings: Any,
    slice_spacing: float,
    seed: int,
    metadata: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Render and write a 3D recording: ``volume_<k>.tif`` (a multi-page 16-bit TIFF,
    one page per B-scan), ``truth_<k>.vtp`` (the noiseless surface, mm) and
    ``recording.json``.

    Parameters
    ----------
    out : path
        Folder (created).
    surfaces : sequence of Interface
        The deformed colony surfaces, one per loading, mm.
    factors : sequence of float
        Loading factors (``k`` is the position).
    nominal : float
        Nominal inflow rate, mm^3/s.
    settings : bayescalib.geometry.recording.ScanSettings
    slice_spacing : float
        Distance between B-scans, mm.
    seed : int
        Seed of the speckle and noise generator.
    metadata : mapping, optional
        Merged into ``recording.json``.

    Returns
    -------
    dict
        The content of ``recording.json``.
    """
    import json
    from dataclasses import asdict

    import tifffile

    from bayescalib.geometry.recording import (
        COUNTS_PER_CONTRAST,
        INTENSITY_OFFSET,
        encode_counts,
    )
    from bayescalib.geometry.recording3d import render_volume, volume_grid
    from bayescalib.io.observations import write_interface_vtk

    if len(surfaces) != len(factors):
        raise ValueError("one surface per loading factor is needed")
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    allpts = np.vstack([s.points for s in surfaces])
    shape, origin = volume_grid(np.array([allpts.min(axis=0), allpts.max(axis=0)]), settings,
                                slice_spacing)
    rng = np.random.default_rng(seed)
    volumes = []
    for k, (surf, f) in enumerate(zip(surfaces, factors, strict=True)):
        img = render_volume(surf, shape=shape, origin=origin, slice_spacing=slice_spacing,
                            settings=settings, rng=rng)
        name = f"volume_{k}.tif"
        tifffile.imwrite(folder / name, encode_counts(img), compression="zlib")
        write_interface_vtk(folder / f"truth_{k}.vtp", surf)
        volumes.append({"file": name, "loading_factor": float(f),
                        "inflow_rate_mm3_per_s": float(f) * float(nominal),
                        "truth_surface": f"truth_{k}.vtp"})
    um = 1000.0
    record: dict[str, Any] = {
        "format": "bayescalib synthetic OCT volume recording 1",
        "units": "um",
        "voxel_size": [settings.pixel_size * um, settings.pixel_size * um, slice_spacing * um],
        "origin": [v * um for v in origin],
        "origin_is": "centre of voxel [0, ny-1, 0]: the first B-scan's bottom-left pixel; x "
                     "downstream, y up, z across; each TIFF page is a B-scan, row 0 the top",
        "volume_shape": [int(v) for v in shape],
        "floor": {"y": 0.0, "rows_below": settings.rows_below_floor,
                  "substrate_rows": settings.rows(settings.substrate_thickness)},
        "intensity": {"counts_per_contrast": COUNTS_PER_CONTRAST, "offset": INTENSITY_OFFSET,
                      "decode": "I = counts / counts_per_contrast - offset (fluid 0, biofilm 1)",
                      "substrate": settings.substrate_intensity},
        "render": {**asdict(settings), "slice_spacing": slice_spacing},
        "render_units": "pixel_size, slice_spacing, margin, substrate_thickness, "
                        "below_substrate in mm; psf_sigma in pixels; noise in units of the "
                        "contrast",
        "noise_seed": int(seed),
        "inflow_nominal_mm3_per_s": float(nominal),
        "volumes": volumes,
        "truth_surfaces": "truth_<k>.vtp: the noiseless model surface (mm)",
        **dict(metadata or {}),
    }
    (folder / "recording.json").write_text(json.dumps(record, indent=1) + "\n")
    return record
