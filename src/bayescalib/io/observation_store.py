"""HDF5 storage of an observation set (the pipeline's ``observations.h5``).

Layout (lengths in mm)::

    /snapshots/<k>/points   (n_k, d)   ordered interface nodes of snapshot k
    /snapshots/<k>/cells    (m_k, d)   segments (d = 2) or triangles (d = 3)
        attrs: label (str), load (float, NaN if unknown),
               segmentation (JSON, optional: how an image snapshot was segmented,
               with sigma_mm, the segmentation's positional uncertainty, mm)
    /reference/points, /reference/cells   optional undeformed interface
    attrs: units = "mm", n_snapshots, format_version, complete = 1 (written last)

Files are written atomically; a file without ``complete`` is rejected.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.geometry.interface import Interface
from bayescalib.io._atomic_write import atomic_path
from bayescalib.io.header import validate_header, write_header

__all__ = ["StoredObservations", "read_observations", "write_observations"]



@dataclass
class StoredObservations:
    """An observation set with its optional undeformed reference and metadata.

    Attributes
    ----------
    snapshots
        Observed interfaces, one per snapshot (e.g. per inflow rate).
    labels
        One label per snapshot.
    loads
        Loading of each snapshot (e.g. inflow rate in mm^2/s), NaN if unknown.
    reference
        Undeformed interface (no-flow scan or the model's reference), if known.
    meta
        JSON-serializable provenance (source, noise level, seed, files).
    segmentation
        Per snapshot, what :func:`bayescalib.io.observations.read_interface_info` said
        about an image (kind mask/scan, threshold, floor, ``sigma_mm``: the
        segmentation's positional uncertainty of the interface in mm, None for
        masks), a volume or a surface file (kind volume/surface, the floor it was cut
        at), or None (coordinate files, synthetic data); None: none at all.
    """

    snapshots: list[Interface]
    labels: list[str]
    loads: list[float | None]
    reference: Interface | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    segmentation: list[dict[str, Any] | None] | None = None

    def __post_init__(self) -> None:
        if not self.snapshots:
            raise ValueError("an observation set needs at least one snapshot")
        if not (len(self.snapshots) == len(self.labels) == len(self.loads)):
            raise ValueError("snapshots, labels and loads must have the same length")
        if self.segmentation is not None and len(self.segmentation) != len(self.snapshots):
            raise ValueError(f"{len(self.segmentation)} segmentation record(s) for "
                             f"{len(self.snapshots)} snapshot(s)")

    def cut_heights(self) -> list[float | None]:
        """Per snapshot, :func:`bayescalib.io.observations.cut_height`: the plane a 3D
        observed surface was cut at above the floor, or None; the model's surface is
        compared above it (:func:`bayescalib.stages.discrepancy.model_interfaces`)."""
        from bayescalib.io.observations import cut_height

        segs = self.segmentation or [None] * len(self.snapshots)
        return [cut_height(snap, seg) for snap, seg in zip(self.snapshots, segs)]

    def segmentation_sigma(self) -> float | None:
        """The segmentation's positional uncertainty of the observed interfaces, mm: the
        root mean square of ``sigma_mm`` over the snapshots segmented from raw scans
        (:mod:`bayescalib.geometry.imaging`), or None when no snapshot has one (masks,
        coordinate files, synthetic data)."""
        vals = [float(r["sigma_mm"]) for r in (self.segmentation or [])
                if r and r.get("sigma_mm") is not None]
        return float(np.sqrt(np.mean(np.square(vals)))) if vals else None


def _write_iface(group, iface: Interface) -> None:
    group.create_dataset("points", data=np.asarray(iface.points, dtype=float))
    group.create_dataset("cells", data=np.asarray(iface.cells, dtype=np.int64))


def _read_iface(group, name: str) -> Interface:
    pts = np.asarray(group["points"][...], dtype=float)
    cells = np.asarray(group["cells"][...], dtype=np.int64)
    if pts.shape[1] == 2:
        return Interface.polyline(pts, cells, name=name)
    return Interface.surface(pts, cells, name=name)


def write_observations(path: str | Path, obs: StoredObservations) -> None:
    """Write ``obs`` to ``path`` atomically."""
    import h5py

    with atomic_path(path, suffix=".h5") as tmp, h5py.File(tmp, "w") as f:
        snaps = f.create_group("snapshots")
        for k, (iface, label, load) in enumerate(
            zip(obs.snapshots, obs.labels, obs.loads, strict=True)
        ):
            g = snaps.create_group(str(k))
            _write_iface(g, iface)
            g.attrs["label"] = str(label)
            g.attrs["load"] = float("nan") if load is None else float(load)
            seg = obs.segmentation[k] if obs.segmentation is not None else None
            if seg is not None:
                g.attrs["segmentation"] = json.dumps(seg, sort_keys=True)
        if obs.reference is not None:
            _write_iface(f.create_group("reference"), obs.reference)
        f.attrs["units"] = "mm"
        f.attrs["n_snapshots"] = len(obs.snapshots)
        f.attrs["meta"] = json.dumps(obs.meta, sort_keys=True)
        write_header(f, "observations")
        f.attrs["complete"] = 1


def read_observations(path: str | Path) -> StoredObservations:
    """Read an observation set written by :func:`write_observations`.

    Raises
    ------
    ValueError
        Naming the file, if it is missing, truncated or incomplete.
    """
    import h5py

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"observation file '{p}' does not exist")
    try:
        with h5py.File(p, "r") as f:
            validate_header(f, "observations", p)
            if int(f.attrs.get("complete", 0)) != 1:
                raise ValueError(f"observation file '{p}' is incomplete (interrupted write?)")
            n = int(f.attrs["n_snapshots"])
            snaps, labels, loads, segs = [], [], [], []
            for k in range(n):
                g = f["snapshots"][str(k)]
                label = str(g.attrs["label"])
                snaps.append(_read_iface(g, label))
                labels.append(label)
                load = float(g.attrs["load"])
                loads.append(load)
                seg = g.attrs.get("segmentation")
                segs.append(None if seg is None else json.loads(str(seg)))
            ref = _read_iface(f["reference"], "reference") if "reference" in f else None
            meta = json.loads(str(f.attrs.get("meta", "{}")))
    except (OSError, KeyError) as exc:
        raise ValueError(f"observation file '{p}' is unreadable or corrupt: {exc}") from None
    return StoredObservations(snaps, labels, [None if math.isnan(x) else x for x in loads],
                              ref, meta, segs if any(x is not None for x in segs) else None)
