"""Stage ``discrepancy`` (rule ``discrepancy``): the discrepancy D between one design
point's solve and the observations, for one measure, and its Gaussian log-likelihood.

For each observation snapshot, the measure (paper Sec. 2.4: the Euclidean distance at
measurement points, eq:eucliddist; the closest point projection, eq:cppdist; the RKHS
norm of surface currents, eq:rkhs_norm) gives D and the number n of measurements; the
log-likelihood is eq:loglik, -n/2 log(2 pi sigma_N^2) - D^2 / (2 sigma_N^2), summed over
the snapshots. A failed solve is a record with no log-likelihood (-inf: left out of the
training). :func:`model_interfaces` pairs each snapshot with the model's interface (also
for the diagnosis), and interfaces too far apart in size or position for a misfit are
refused as a unit slip (:data:`SCALE_FACTOR`). Curves (2D model) and surfaces (3D model,
the run record's triangles) take the same path; a model and observations of different
dimensions are refused.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.stages.errors import PipelineError
from bayescalib.stages.files import read_stage_file, write_json

__all__ = ["SCALE_FACTOR", "discrepancy", "model_interfaces"]


def discrepancy(run_path: str | Path, obs_path: str | Path, measure_name: str,
                measure: Mapping[str, Any], likelihood: Mapping[str, Any],
                out_path: str | Path) -> dict[str, Any]:
    """D, distance vector and log-likelihood of one design point for one measure.

    ``measure`` holds the validated options of this measure only (the section
    ``measure.<measure_name>``), so that a job depends on nothing else. A failed
    run gives ``loglik = None`` (i.e. -inf: excluded from training).
    """
    from bayescalib.inference.likelihood import gaussian_loglik
    from bayescalib.measures import compute

    run = read_stage_file(run_path, "run record")
    obs = read_stage_file(obs_path, "observation set")
    record: dict[str, Any] = {
        "measure": measure_name,
        "status": run.status,
        "reason": run.reason,
        "parameters": run.parameters,
    }
    if run.status != "ok":
        record.update(D=None, n=None, loglik=None, snapshots=[])
        write_json(out_path, record)
        return record
    if run.loadings and len(run.loadings) != len(obs.snapshots):
        raise PipelineError(
            f"run '{run_path}' has {len(run.loadings)} loadings but the observation set "
            f"'{obs_path}' has {len(obs.snapshots)} snapshots: give one snapshot per loading"
        )
    models = model_interfaces(run, len(obs.snapshots), obs.cut_heights())
    for label, snap, model in zip(obs.labels, obs.snapshots, models, strict=True):
        if model.dim != snap.dim:
            what = {2: "a 2D curve", 3: "a 3D surface"}
            raise PipelineError(
                f"observed interface '{label}' ({obs_path}) is {what[snap.dim]} but the "
                f"model's ('{run_path}') is {what[model.dim]}: a {model.dim}D model is "
                f"calibrated on {model.dim}D observations (forward_model.fsi.geometry.dim)")
        _validate_scales(np.asarray(model.points), np.asarray(snap.points), label, obs_path)
    sigma_n2 = _sigma_n2(likelihood)
    options = _measure_options(measure_name, measure, obs)
    total, snaps = 0.0, []
    from bayescalib.measures import MeasureOptionError

    for label, snap, model in zip(obs.labels, obs.snapshots, models, strict=True):
        try:
            res = compute(measure_name, model, snap, **options)
        except MeasureOptionError:
            raise
        except ValueError as exc:  # e.g. a ray missing the model with on_miss: raise
            record.update(status="failed", reason=f"measure {measure_name}: {exc}", D=None,
                          n=None, loglik=None, snapshots=[])
            write_json(out_path, record)
            return record
        ll = gaussian_loglik(res.D, res.n, sigma_n2)
        total += ll
        snaps.append({"label": label, "D": res.D, "n": res.n, "loglik": ll,
                      "distances": np.atleast_1d(res.distances)})
    record.update(D=float(np.sqrt(sum(s["D"] ** 2 for s in snaps))),
                  n=int(sum(s["n"] for s in snaps)), loglik=total, sigma_n2=sigma_n2,
                  snapshots=snaps)
    write_json(out_path, record)
    return record


#: observed and model interfaces further apart in size or position than this factor
#: are a unit slip, not a misfit
SCALE_FACTOR = 10.0


def _validate_scales(model: np.ndarray, observed: np.ndarray, label: str, obs_path) -> None:
    """Refuse to compare interfaces whose sizes or positions differ by more than
    :data:`SCALE_FACTOR`: a discrepancy between them would be a number without meaning
    (typically observations in m or um read as mm)."""
    ext_m = float(np.max(np.ptp(model, axis=0)))
    ext_o = float(np.max(np.ptp(observed, axis=0)))
    size = max(ext_m, ext_o)
    if size <= 0:
        return
    ratio = max(ext_m, ext_o) / max(min(ext_m, ext_o), 1e-300)
    shift = float(np.linalg.norm(model.mean(axis=0) - observed.mean(axis=0)))
    if ratio > SCALE_FACTOR or shift > SCALE_FACTOR * size:
        raise PipelineError(
            f"observed interface '{label}' ({obs_path}) spans {ext_o:.4g} mm around "
            f"{np.round(observed.mean(axis=0), 4).tolist()}, the model's {ext_m:.4g} mm around "
            f"{np.round(model.mean(axis=0), 4).tolist()} (size ratio {ratio:.3g}): more than "
            f"{SCALE_FACTOR:g}x apart, which is a unit slip rather than a misfit. Check "
            "observations.files[].units (mm, m, um), pixel_size and origin.")


def model_interfaces(run, n_snapshots: int, cuts: Sequence[float | None] | None = None
                     ) -> list:
    """The predicted interface for each observation snapshot: one per loading of a series,
    or the single interface repeated (every snapshot compared with the same solve).

    ``cuts`` (per snapshot, :meth:`~bayescalib.io.observation_store.StoredObservations.
    cut_heights`): a 3D surface is compared above the plane its observed snapshot was cut
    at (the part of the model's surface above it, triangles crossing it cut along it),
    since the observation holds nothing below it: an OCT volume's floor lies on top of
    the bright substrate's halo, one or two voxels above the substrate (measured on the
    3D example recording: 12 um at 6 um voxels), and the colony's foot below it, absent
    from the data, would otherwise count as a misfit (there, an RKHS distance of 0.0088
    against 0.0004 above the cut)."""
    from bayescalib.geometry.interface import Interface
    from bayescalib.geometry.surface import surface_above

    if run.loadings:
        out = [Interface(ld.current, run.segments, name=f"model {ld.label}")
               for ld in run.loadings]
    else:
        out = [Interface(run.interface_current, run.segments, name="model")] * n_snapshots
    for k, y in enumerate(cuts or ()):
        if y is not None and out[k].dim == 3:
            out[k] = surface_above(out[k], y)
    return out


def _sigma_n2(likelihood: Mapping[str, Any]) -> float:
    from bayescalib.inference.likelihood import sigma_n2_from_config

    return sigma_n2_from_config(likelihood)


def _measure_options(name: str, options: Mapping[str, Any], obs) -> dict[str, Any]:
    """Keyword options of measure ``name``: its config options, plus the observed
    reference configuration for the Euclidean measure."""
    sub = dict(options)
    if name == "euclidean" and obs.reference is not None and "reference" not in sub:
        sub["reference"] = obs.reference
    return sub
