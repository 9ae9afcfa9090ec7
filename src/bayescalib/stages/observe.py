"""Stage ``observe`` (rule ``observe``, ``scripts/observe.py``): the observation set,
``observations.h5``.

Synthetic observations are the interfaces of the forward solve at the ground truth (one
snapshot per loading of a series; curves of the 2D model, triangulated surfaces of the 3D
one, each with the run record's cells), misplaced by ``observations.misregistration`` and
with Gaussian noise of ``observations.noise_sigma`` added, from the one generator of
``observations.seed``; observations from files are the interfaces read from the files
listed (coordinate files, CSV or VTK, or images: masks, and scans segmented here; in 3D
surfaces, STL, PLY or VTK, and OCT volumes segmented here),
each with its label and load. Every
discrepancy compares a solve with this one set.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.stages.errors import PipelineError
from bayescalib.stages.files import read_stage_file

__all__ = ["observe"]

log = logging.getLogger("bayescalib")


def observe(observations: Mapping[str, Any], out_path: str | Path, *,
            ground_truth_run: str | Path | None = None) -> None:
    """Build the observation set and write ``observations.h5``.

    Parameters
    ----------
    observations
        Validated ``observations`` config section.
    ground_truth_run
        Run record of the forward solve at the ground truth (synthetic source).
    """
    from bayescalib.geometry.interface import Interface
    from bayescalib.io.observation_store import StoredObservations, write_observations
    from bayescalib.io.observations import (
        add_noise,
        read_interface,
        read_interface_info,
        reader_options,
    )

    source = observations["source"]
    if source == "synthetic":
        if ground_truth_run is None:
            raise PipelineError("synthetic observations need the ground-truth run record")
        run = read_stage_file(ground_truth_run, "run record")
        if run.status != "ok":
            raise PipelineError(
                f"the forward solve at the ground truth failed ({run.reason}); synthetic "
                "observations cannot be made: change the ground truth or the forward model"
            )
        reference = Interface(run.interface_reference, run.segments, name="reference")
        sigma = float(observations["noise_sigma"])
        seed = int(observations["seed"])
        rng = np.random.default_rng(seed)
        if run.loadings:  # one snapshot per loading of the series
            curves = [ld.current for ld in run.loadings]
            labels = [ld.label for ld in run.loadings]
            loads = [ld.value for ld in run.loadings]
        else:
            curves, labels = [run.interface_current], ["ground_truth"]
            loads = [run.parameters.get("inflow.rate")]
        misreg = dict(observations.get("misregistration") or {})
        if misreg:  # a hidden misplacement of the images, the same for every snapshot
            from bayescalib.geometry.registration import misplace

            centre = np.asarray(curves[0], dtype=float).mean(axis=0)
            curves = [misplace(pts, misreg, centre) for pts in curves]
        snaps = []
        for pts, label in zip(curves, labels):
            current = Interface(pts, run.segments, name=f"observed {label}")
            snaps.append(add_noise(current, sigma, rng) if sigma > 0 else current)
        stored = StoredObservations(
            snaps, labels, loads, reference,
            {"source": "synthetic", "noise_sigma_mm": sigma, "seed": seed,
             "ground_truth": run.parameters,
             "hidden": dict(observations.get("hidden") or {}),
             **({"misregistration": misreg} if misreg else {})},
        )
    elif source == "files":
        snaps, labels, loads, segs = [], [], [], []
        domain = observations.get("domain")
        for entry in observations["files"]:
            iface, info = read_interface_info(entry["path"], domain=domain,
                                              **reader_options(entry))
            snaps.append(iface)
            labels.append(entry.get("label") or Path(entry["path"]).stem)
            loads.append(entry.get("load"))
            segs.append(info if info["kind"] in ("mask", "scan", "volume", "surface") else None)
            if info["kind"] == "volume":
                log.info("%s: volume %s (%s) segmented at %.6g (%s), floor %s at y = %.6g mm, "
                         "%d colony voxels", entry["path"], "x".join(map(str, info["shape"])),
                         info["image"], info["threshold"], info["threshold_method"],
                         info["floor"]["method"], info["floor"]["y_mm"], info["colony_voxels"])
            if info["kind"] == "scan":
                log.info("%s: scan segmented at %.6g (%s), floor %s, segmentation "
                         "uncertainty %.3g um", entry["path"], info["threshold"],
                         info["threshold_method"], info["floor"]["method"],
                         1e3 * (info["sigma_mm"] or float("nan")))
        if not snaps:
            raise PipelineError("observations.files is empty: list at least one interface file")
        ref = None
        if observations.get("reference"):
            ref_entry = observations["reference"]
            ref = read_interface(ref_entry["path"], domain=domain, **reader_options(ref_entry))
        stored = StoredObservations(snaps, labels, loads, ref,
                                    {"source": "files", "files": observations["files"]},
                                    segs if any(x is not None for x in segs) else None)
    else:
        raise PipelineError(f"observations.source: unknown source {source!r}")
    write_observations(out_path, stored)
    log.info("observation set: %d snapshot(s) -> %s", len(stored.snapshots), out_path)

