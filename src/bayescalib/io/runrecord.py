"""Run records: the result of one forward solve, stored as HDF5 (pure I/O, no solver).

A run record holds the inputs (dotted config keys in user units: Pa, mm, mm^2/s), the
status (``"ok"`` or ``"failed"`` with a reason — a failed solve is data, paper Sec. 4.3),
solver statistics and timing, and the undeformed and deformed fluid–solid interface:
in 2D ordered node coordinates (mm) with segments, in 3D a triangulated surface
(vertices (n, 3), triangles (m, 3) with normals into the fluid).

File layout (the ``run`` kind of :mod:`bayescalib.io.header`)::

    /                     attrs: format="bayescalib-run", format_version, status, reason,
                                 load_fraction, newton_iterations, load_steps, wall_time,
                                 max_displacement, complete (written last)
    /parameters           attrs: one float per dotted key
    /stats                attrs: numbers and strings
    /interface/reference  (n, 2) float64, mm
    /interface/current    (n, 2) float64, mm
    /interface/segments   (n - 1, 2) int64 (a curve), or
    /interface/triangles  (m, 3) int64 (a surface; then reference and current are (n, 3))
    /loadings/<k>/current (n, 2) float64, mm: optional, one per loading of a series
                          (attrs: label, factor, value = the loaded parameter's value)

Writing is atomic: the file is written to a temporary name in the same directory and
moved into place with :func:`os.replace`; the ``complete`` attribute is set as the last
write, so a file cut short is detected by :func:`read_run` (raises :class:`RunFileError`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bayescalib.io._atomic_write import atomic_path
from bayescalib.io.header import validate_header, write_header

__all__ = [
    "LoadingResult",
    "RunFileError",
    "SolveResult",
    "read_run",
    "write_run",
]



class RunFileError(ValueError):
    """A run file is missing, truncated, corrupt or incomplete (message names the file)."""


@dataclass
class LoadingResult:
    """The deformed interface at one loading of a series (several snapshots per point).

    Attributes
    ----------
    label
        Snapshot label (matches the observation snapshot).
    factor
        Loading factor relative to the nominal value of the loaded parameter.
    value
        Value of the loaded parameter (e.g. the inflow rate, mm^2/s).
    current
        (n, 2) deformed interface nodes in mm (same nodes as the reference).
    """

    label: str
    factor: float
    value: float
    current: np.ndarray


@dataclass
class SolveResult:
    """Outcome of one forward solve.

    Attributes
    ----------
    status
        ``"ok"`` or ``"failed"``.
    reason
        ``""`` when ok, else a human-readable cause.
    parameters
        Inputs used, user units, by dotted config key (e.g. ``"material.E": 400.0`` Pa).
    load_fraction
        Reached fraction of the target load (inflow) in [0, 1].
    newton_iterations
        Total Newton iterations over all load steps.
    load_steps
        Converged load steps.
    wall_time
        Seconds.
    interface_reference
        (n, 2) undeformed interface nodes in mm, ordered upstream foot -> downstream foot;
        (n, 3) vertices of a surface (3D model).
    interface_current
        (n, 2) or (n, 3) deformed interface nodes in mm (last converged state for a
        failed run).
    segments
        The cells: (n - 1, 2) int indices into the node arrays (a curve), or (m, 3)
        triangles of a surface (``cells`` of
        :class:`bayescalib.geometry.interface.Interface`, normals into the fluid).
    max_displacement
        Max interface node displacement, mm.
    stats
        Anything else (DOFs, interface node count, timings per phase, ...).
    loadings
        Interfaces at each loading of a series (empty for a single loading); then
        ``interface_current`` is the one at the nominal loading (factor 1) if the series
        has it, else the one at the largest factor.
    """

    status: str
    reason: str
    parameters: dict[str, float]
    load_fraction: float
    newton_iterations: int
    load_steps: int
    wall_time: float
    interface_reference: np.ndarray
    interface_current: np.ndarray
    segments: np.ndarray
    max_displacement: float
    stats: dict[str, float | int | str] = field(default_factory=dict)
    loadings: list[LoadingResult] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when the solve reached the full load."""
        return self.status == "ok"


def _attr_value(v):
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v)
    return str(v)


def write_run(path: str | Path, result: SolveResult) -> None:
    """Write ``result`` to the HDF5 file ``path`` atomically (:func:`atomic_path`)."""
    import h5py

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if result.status not in ("ok", "failed"):
        raise ValueError(f"status must be 'ok' or 'failed', got {result.status!r}")
    with atomic_path(path, suffix=".h5") as tmp, h5py.File(tmp, "w") as f:
        write_header(f, "run")
        f.attrs["complete"] = 0
        f.attrs["status"] = result.status
        f.attrs["reason"] = result.reason
        f.attrs["load_fraction"] = float(result.load_fraction)
        f.attrs["newton_iterations"] = int(result.newton_iterations)
        f.attrs["load_steps"] = int(result.load_steps)
        f.attrs["wall_time"] = float(result.wall_time)
        f.attrs["max_displacement"] = float(result.max_displacement)
        f.attrs["units"] = "lengths mm, stresses Pa, inflow rate mm^2/s, time s"
        g = f.create_group("parameters")
        for k, v in result.parameters.items():
            g.attrs[k] = float(v)
        g = f.create_group("stats")
        for k, v in result.stats.items():
            g.attrs[k] = _attr_value(v)
        g = f.create_group("interface")
        g.create_dataset("reference", data=np.asarray(result.interface_reference, dtype=np.float64))
        g.create_dataset("current", data=np.asarray(result.interface_current, dtype=np.float64))
        cells = np.asarray(result.segments, dtype=np.int64)
        g.create_dataset(_cells_name(cells), data=cells)
        if result.loadings:
            g = f.create_group("loadings")
            for k, ld in enumerate(result.loadings):
                d = g.create_dataset(str(k), data=np.asarray(ld.current, dtype=np.float64))
                d.attrs["label"] = str(ld.label)
                d.attrs["factor"] = float(ld.factor)
                d.attrs["value"] = float(ld.value)
        f.flush()
        f.attrs["complete"] = 1


def _cells_name(cells: np.ndarray) -> str:
    """Dataset name of an interface's cells: ``segments`` (k, 2) or ``triangles`` (k, 3)."""
    if cells.ndim != 2 or cells.shape[1] not in (2, 3):
        raise ValueError(f"interface cells must be segments (k, 2) or triangles (k, 3), "
                         f"got shape {cells.shape}")
    return "segments" if cells.shape[1] == 2 else "triangles"


def _plain(v):
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.generic):
        return v.item()
    return v


def read_run(path: str | Path) -> SolveResult:
    """Read a run record written by :func:`write_run`.

    Raises
    ------
    RunFileError
        Naming the file, if it is missing, not HDF5, truncated, of another format or
        version, or incomplete.
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        raise RunFileError(f"run file '{path}' does not exist")
    try:
        with h5py.File(path, "r") as f:
            validate_header(f, "run", path, RunFileError)
            if int(_plain(f.attrs.get("complete", 0))) != 1:
                raise RunFileError(f"run file '{path}' is incomplete (writing was interrupted)")
            a = f.attrs
            res = SolveResult(
                status=str(_plain(a["status"])),
                reason=str(_plain(a["reason"])),
                parameters={k: float(_plain(v)) for k, v in f["parameters"].attrs.items()},
                load_fraction=float(_plain(a["load_fraction"])),
                newton_iterations=int(_plain(a["newton_iterations"])),
                load_steps=int(_plain(a["load_steps"])),
                wall_time=float(_plain(a["wall_time"])),
                interface_reference=np.array(f["interface/reference"], dtype=float),
                interface_current=np.array(f["interface/current"], dtype=float),
                segments=np.array(f["interface/triangles" if "triangles" in f["interface"]
                                    else "interface/segments"], dtype=np.int64),
                max_displacement=float(_plain(a["max_displacement"])),
                stats={k: _plain(v) for k, v in f["stats"].attrs.items()},
                loadings=[
                    LoadingResult(str(_plain(d.attrs["label"])), float(_plain(d.attrs["factor"])),
                                  float(_plain(d.attrs["value"])), np.array(d, dtype=float))
                    for d in (f["loadings"][str(k)] for k in range(len(f["loadings"])))
                ] if "loadings" in f else [],
            )
    except RunFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise RunFileError(f"run file '{path}' is corrupt or truncated: {exc}") from None
    n = res.interface_reference.shape
    if (
        len(n) != 2
        or n[1] not in (2, 3)
        or res.interface_current.shape != n
        or res.segments.ndim != 2
        or res.segments.shape[1] not in (2, 3)
        or (res.segments.shape[1] == 3 and n[1] != 3)
        or res.status not in ("ok", "failed")
    ):
        raise RunFileError(f"run file '{path}' is inconsistent (interface arrays or status)")
    return res
