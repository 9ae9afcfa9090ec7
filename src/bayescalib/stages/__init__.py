"""Pipeline stages: one function per Snakemake rule, over plain values and paths.

The rule scripts in ``scripts/`` only unpack ``snakemake.input/params/output``
and call these functions, so every stage can be run and tested without
Snakemake. Each stage reads its inputs, does its one job with the library, and
writes its outputs atomically, so an interrupted run never leaves a
half-written file that a later run would trust.

Stages (paper Sec. 3, Fig. "workflow"):

``observe``         observation set (synthetic from a ground-truth solve, or files)
``discrepancy``     D and log-likelihood of one design point for one measure
``gather``          training table of all design points
``train_surrogate`` GP surrogate of the log-likelihood
``convergence``     GP error over n_train on held-out Sobol points
``smc``             SMC particles on the surrogate
``acquire``         active design: checks, stop rule and next batch of a round
``marginalize``     posterior summaries and ArviZ export
"""

from __future__ import annotations

import json
import logging
import math
import os
import sys
import zipfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.io._atomic_write import atomic_path
from bayescalib.io.training import read_training, write_training

__all__ = [
    "PipelineError",
    "acquire",
    "convergence",
    "design_summary",
    "discrepancy",
    "front_page",
    "gather",
    "gather_rows",
    "marginalize",
    "observe",
    "read_json",
    "read_stage_file",
    "run_line",
    "smc",
    "train_surrogate",
    "write_json",
]

log = logging.getLogger("bayescalib")


class PipelineError(RuntimeError):
    """A stage cannot proceed; the message says what to change."""


# ----------------------------------------------------------------------------- json
def _clean(obj: Any) -> Any:
    """Make ``obj`` strict-JSON serializable (non-finite floats become None)."""
    if isinstance(obj, Mapping):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def write_json(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as indented strict JSON, atomically."""
    with atomic_path(path, suffix=".json") as tmp:
        tmp.write_text(json.dumps(_clean(obj), indent=2, sort_keys=False, allow_nan=False) + "\n")


def read_json(path: str | Path) -> Any:
    """A JSON file read only to look at it (the report's front page at parse time,
    ``bayescalib summary``): a file that cannot be read is left where it is. A stage
    reads the outputs of other stages through :func:`read_stage_file`."""
    p = Path(path)
    try:
        return json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise PipelineError(f"cannot read JSON file '{p}': {exc}") from None


def setup_logging(path: str | Path | None) -> None:
    """Send the library's log records to ``path`` (a rule's log file) and stderr.

    With a log file (a job of the workflow), the console gets warnings and errors only:
    a study runs thousands of jobs, and their information is in their logs. Python's
    warnings (the libraries': GPy's and NumPy's RuntimeWarnings, Matplotlib's, with
    their site-packages paths) go to the log file only, not to the console.
    """
    root = logging.getLogger("bayescalib")
    root.setLevel(logging.INFO)
    fmt = logging.Formatter("%(asctime)s %(levelname)s %(message)s")
    console = logging.StreamHandler()
    if path is not None:
        console.setLevel(logging.WARNING)
    handlers: list[logging.Handler] = [console]
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        handlers.append(logging.FileHandler(path, mode="w"))
    for h in handlers:
        h.setFormatter(fmt)
        root.addHandler(h)
    if path is not None:
        logging.captureWarnings(True)
        warned = logging.getLogger("py.warnings")
        warned.propagate = False  # not to the console (the root logger's last resort)
        for h in [h for h in warned.handlers if getattr(h, "_bayescalib_log", False)]:
            warned.removeHandler(h)  # an earlier job's log in this process
        warned.addHandler(handlers[-1])
        handlers[-1]._bayescalib_log = True  # type: ignore[attr-defined]
        # a job of a study (its log under <root>/logs/) marks itself running, so that a
        # new run of the study waits for the orphans of a killed one
        parts = Path(path).resolve().parts
        if "logs" in parts:
            from bayescalib.study import hold_job_lock

            hold_job_lock(Path(*parts[: len(parts) - 1 - parts[::-1].index("logs")]))
        # an error that ends the job goes into the rule's log too, not only to the console
        previous = sys.excepthook

        file_handler = handlers[-1]

        def _log_and_raise(kind, exc, tb):
            if not issubclass(kind, KeyboardInterrupt):
                file_handler.handle(root.makeRecord(
                    root.name, logging.ERROR, __file__, 0, "%s: %s", (kind.__name__, exc),
                    (kind, exc, tb)))
                file_handler.flush()
            previous(kind, exc, tb)

        sys.excepthook = _log_and_raise


# ------------------------------------------------------------------ stage files
def _set_aside(path: str | Path, problem: str, *,
               rebuilt_by_this_run: bool = False) -> PipelineError:
    """Move a stage output that cannot be used to ``<name>.corrupt`` and say how to
    redo it.

    The file is the output of an upstream job. Every stage output is a target of the
    workflow (``study_outputs``), and the job that failed on it wrote nothing, so the
    next run of the same ``snakemake`` command rebuilds the missing file and what
    depends on it, instead of failing on it again. For run records and discrepancy
    files the gather rule lists the set-aside files as a parameter, so gather reruns
    too. ``rebuilt_by_this_run``: set aside before Snakemake builds its plan, which
    then rebuilds the file in this run (the message says so).
    """
    p = Path(path)
    aside = p.with_name(p.name + ".corrupt")
    k = 1
    while aside.exists():  # every event gets its own name (the gather rule lists them)
        aside = p.with_name(f"{p.name}.{k}.corrupt")
        k += 1
    where = ""
    if p.exists():
        try:
            os.replace(p, aside)
            where = f"; it was moved to '{aside}'"
        except OSError as exc:  # pragma: no cover - read-only results folder
            where = f"; it could not be moved aside ({exc}): delete it"
    then = ("This run recomputes it." if rebuilt_by_this_run else
            "Run the same snakemake command again: it is recomputed, and only what "
            "depends on it.")
    return PipelineError(f"{problem}{where}. {then}")


def _json_object(path: Path) -> dict[str, Any]:
    """A JSON stage output: an object (every stage writes one)."""
    value = json.loads(path.read_bytes())
    if not isinstance(value, dict):
        raise ValueError(f"it holds a JSON {type(value).__name__}, not an object")
    return value


def _run_record(path: Path, **options: Any):
    from bayescalib.io.runrecord import read_run

    return read_run(path, **options)


def _observation_set(path: Path, **options: Any):
    from bayescalib.io.observation_store import read_observations

    return read_observations(path, **options)


def _surrogate(path: Path, **options: Any):
    from bayescalib.inference.emulator import load_surrogate

    return load_surrogate(path, **options)


def _particles(path: Path, **options: Any):
    from bayescalib.inference.posterior import read_particles_h5

    return read_particles_h5(path, **options)


def _warm_start_state(path: Path) -> dict[str, Any]:
    """The arrays of a warm-start state (``FSIModel.save_state``), read in full."""
    with np.load(path, allow_pickle=False) as data:
        return {"state": np.array(data["state"], dtype=float), "key": str(data["key"]),
                "parameters": json.loads(str(data["parameters"]))}


def _vtu_fields(path: Path):
    from bayescalib.stages.figures import read_vtu_fields

    return read_vtu_fields(path)


#: every kind of file a stage reads from another stage: its reader (the one place that
#: knows each format). JSON: the discrepancy, posterior, convergence, posterior-check,
#: active-round and study records; HDF5: run records, the observation set, training
#: tables, surrogates, particles; NumPy: the warm-start state; VTK: the fields.
STAGE_FILES: dict[str, Callable[..., Any]] = {
    "run record": _run_record,
    "observation set": _observation_set,
    "training table": read_training,
    "surrogate": _surrogate,
    "SMC particle file": _particles,
    "warm-start state": _warm_start_state,
    "VTU field file": _vtu_fields,
    "discrepancy record": _json_object,
    "posterior summary": _json_object,
    "GP convergence record": _json_object,
    "posterior check": _json_object,
    "active round record": _json_object,
    "study summary": _json_object,
}

#: what a reader raises on a file it cannot read (a missing, truncated, corrupt file, one
#: of another kind or layout version, a JSON file cut short or not an object)
_UNREADABLE = (OSError, KeyError, ValueError, TypeError, EOFError, IndexError,
               zipfile.BadZipFile)


def read_stage_file(path: str | Path, kind: str, *, rebuilt_by_this_run: bool = False,
                    **options: Any) -> Any:
    """Read the stage output ``path``, a file of ``kind`` (a key of :data:`STAGE_FILES`).

    The one reader of every file a stage reads from another stage, whatever its format.
    A file that cannot be read (missing, truncated, corrupt, of another kind or layout
    version) is moved aside to ``<name>.corrupt`` (:func:`_set_aside`), so that the next
    run of the same ``snakemake`` command rebuilds it, and what depends on it, instead
    of failing on it again (``rebuilt_by_this_run``: read before Snakemake builds its
    plan, which then rebuilds it in this run; the message says so). ``options`` go to
    the kind's reader (e.g. ``device`` of a surrogate).

    Raises
    ------
    PipelineError
        Naming the file, what it is and why it cannot be read, where it was moved and
        what to run.
    """
    try:
        reader = STAGE_FILES[kind]
    except KeyError:
        raise ValueError(f"read_stage_file: unknown kind of stage file {kind!r} "
                         f"(known: {', '.join(STAGE_FILES)})") from None
    p = Path(path)
    try:
        return reader(p, **options)
    except _UNREADABLE as exc:
        from bayescalib.io.runrecord import RunFileError

        why = str(exc) if isinstance(exc, RunFileError) else f"{type(exc).__name__}: {exc}"
        raise _set_aside(p, f"the {kind} '{p}' cannot be read ({why})",
                         rebuilt_by_this_run=rebuilt_by_this_run) from None


# -------------------------------------------------------------------------- observe
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
    from bayescalib.io.observations import add_noise, read_interface, read_interface_info

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
        reference = Interface.polyline(run.interface_reference, run.segments, name="reference")
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
            current = Interface.polyline(pts, run.segments, name=f"observed {label}")
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
                                              **_reader_options(entry))
            snaps.append(iface)
            labels.append(entry.get("label") or Path(entry["path"]).stem)
            loads.append(entry.get("load"))
            segs.append(info if info["kind"] in ("mask", "scan") else None)
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
            ref = read_interface(ref_entry["path"], domain=domain, **_reader_options(ref_entry))
        stored = StoredObservations(snaps, labels, loads, ref,
                                    {"source": "files", "files": observations["files"]},
                                    segs if any(x is not None for x in segs) else None)
    else:
        raise PipelineError(f"observations.source: unknown source {source!r}")
    write_observations(out_path, stored)
    log.info("observation set: %d snapshot(s) -> %s", len(stored.snapshots), out_path)


def _reader_options(entry: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword arguments of :func:`bayescalib.io.observations.read_interface` for one
    ``observations.files`` entry (the keys given, none of the unset ones)."""
    keys = ("units", "pixel_size", "origin", "drop_border", "floor", "image", "segmentation")
    return {k: entry[k] for k in keys if entry.get(k) is not None}


# --------------------------------------------------------------------- discrepancy
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
    models = model_interfaces(run, len(obs.snapshots))
    for label, snap, model in zip(obs.labels, obs.snapshots, models, strict=True):
        _check_scales(np.asarray(model.points), np.asarray(snap.points), label, obs_path)
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


def _check_scales(model: np.ndarray, observed: np.ndarray, label: str, obs_path) -> None:
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


def model_interfaces(run, n_snapshots: int) -> list:
    """The predicted interface for each observation snapshot: one per loading of a series,
    or the single interface repeated (every snapshot compared with the same solve)."""
    from bayescalib.geometry.interface import Interface

    if run.loadings:
        return [Interface.polyline(ld.current, run.segments, name=f"model {ld.label}")
                for ld in run.loadings]
    return [Interface.polyline(run.interface_current, run.segments, name="model")] * n_snapshots


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


# --------------------------------------------------------------------------- gather
def gather_rows(run_paths: Sequence[str | Path], disc_paths: Sequence[str | Path],
                targets: Sequence[str]) -> dict[str, Any]:
    """The rows of a training table from run records and their discrepancy records.

    Returns ``X (n, d)`` (columns in the order of ``targets``), ``loglik (n,)``
    (-inf for failed runs), ``D (n,)``, ``status (n,)`` (1 ok, 0 failed),
    ``bound (n,)`` (:func:`record_bound`, NaN for failed runs), ``n_measurements``
    (n,) (summed over snapshots, NaN for failed runs), ``residuals`` (n, m)
    (:func:`record_residuals`; rows of NaN for failed runs) and ``reason`` (n strings).
    """
    if len(run_paths) != len(disc_paths):
        raise PipelineError("gather: the number of run records and discrepancy files differ")
    n, d = len(run_paths), len(targets)
    X = np.full((n, d), np.nan)
    L = np.full(n, -np.inf)
    D = np.full(n, np.nan)
    ok = np.zeros(n, dtype=np.int8)
    bound = np.full(n, np.nan)
    n_meas = np.full(n, np.nan)
    reasons: list[str] = []
    res_rows: dict[int, np.ndarray] = {}
    for i, (rp, dp) in enumerate(zip(run_paths, disc_paths, strict=True)):
        run = read_stage_file(rp, "run record")
        missing = [t for t in targets if t not in run.parameters]
        if missing:
            raise _set_aside(rp, f"run file '{rp}' has no value for {', '.join(missing)} "
                                 f"(it has {', '.join(sorted(run.parameters)) or 'none'}): "
                                 "it was written for another parameter setup")
        X[i] = [run.parameters[t] for t in targets]
        rec = read_stage_file(dp, "discrepancy record")
        if run.status == "ok" and rec.get("loglik") is not None:
            L[i] = float(rec["loglik"])
            D[i] = float(rec["D"])
            ok[i] = 1
            bound[i] = record_bound(rec)
            n_meas[i] = sum(float(s_["n"]) for s_ in rec.get("snapshots") or []) or math.nan
            r_i = record_residuals(rec)
            if r_i is not None:
                res_rows[i] = r_i
        reasons.append(run.reason or rec.get("reason") or "")
    return {"X": X, "loglik": L, "D": D, "status": ok, "bound": bound,
            "n_measurements": n_meas, "reason": reasons,
            "residuals": _residual_matrix(res_rows, n, disc_paths)}


def record_residuals(rec: Mapping[str, Any]) -> np.ndarray | None:
    """The residual vector of a discrepancy record in noise units, (m,): the distance
    vectors of its snapshots, concatenated, over sigma_N. Its half squared norm is the
    misfit, ``loglik = bound - |r|^2 / 2`` (eq:loglik with D^2 = |d|^2 summed over
    snapshots); for the RKHS measure, whose distance vector is [D], it is D / sigma_N.
    None for a failed run or a record without distance vectors."""
    snaps = rec.get("snapshots") or []
    if rec.get("loglik") is None or not rec.get("sigma_n2") or not snaps \
            or any("distances" not in s_ for s_ in snaps):
        return None
    d = np.concatenate([np.atleast_1d(np.asarray(s_["distances"], float)) for s_ in snaps])
    return d / math.sqrt(float(rec["sigma_n2"]))


def _residual_matrix(rows: Mapping[int, np.ndarray], n: int,
                     disc_paths: Sequence[str | Path]) -> np.ndarray:
    """(n, m) residual matrix, NaN rows where a record has none; m = 0 when none has."""
    widths = {len(v) for v in rows.values()}
    if len(widths) > 1:
        by_width: dict[int, int] = {}
        for i, v in rows.items():
            by_width.setdefault(len(v), i)
        seen = ", ".join(f"{w} in '{disc_paths[i]}'" for w, i in sorted(by_width.items()))
        raise PipelineError(
            f"the discrepancy records' distance vectors differ in length ({seen}): the "
            "model interfaces of these solves have different numbers of nodes (another mesh) "
            "or the measure's points changed. Rerun the discrepancy jobs of one setup.")
    m = widths.pop() if widths else 0
    R = np.full((n, m), np.nan)
    for i, v in rows.items():
        R[i] = v
    return R


def gather(run_paths: Sequence[str | Path], disc_paths: Sequence[str | Path],
           names: Sequence[str], targets: Sequence[str], n_train: int | None,
           out_path: str | Path) -> None:
    """Training table of all design points for one measure (HDF5).

    Datasets: ``X (n, d)`` inputs in user units (columns = parameter names),
    ``loglik (n,)`` (-inf for failed runs), ``D (n,)``, ``status`` (1 ok, 0
    failed), ``is_train`` (first ``n_train`` points; the rest are held out for
    the convergence study; ``n_train=None``: all), ``reason`` (str per point),
    ``bound (n,)``: the largest value the point's Gaussian log-likelihood can take,
    -n/2 log(2 pi sigma_N^2) summed over snapshots (NaN for failed runs),
    ``residuals (n, m)``: each point's residual vector in noise units
    (:func:`record_residuals`), what an output emulator is trained on.
    """
    rows = gather_rows(run_paths, disc_paths, targets)
    n = len(rows["loglik"])
    write_training(out_path, rows["X"], rows["loglik"], rows["D"], rows["status"],
                   rows["reason"], names, n if n_train is None else n_train, bound=rows["bound"],
                   n_measurements=rows["n_measurements"], residuals=rows["residuals"])


def record_bound(rec: Mapping[str, Any]) -> float:
    """The largest value the log-likelihood of a discrepancy record can take,
    sum over snapshots of -n/2 log(2 pi sigma_N^2) (NaN without the record's data)."""
    from bayescalib.inference.likelihood import gaussian_loglik

    if not (rec.get("sigma_n2") and rec.get("snapshots")):
        return math.nan
    return float(sum(gaussian_loglik(0.0, s["n"], rec["sigma_n2"]) for s in rec["snapshots"]))




# ---------------------------------------------------------------- reuse of a round
def _same_bits(u: Any, v: Any) -> bool:
    """Two stored values (datasets or attributes) are the same: equal shapes, dtypes
    and bytes (numeric), or equal elements (strings)."""
    a, b = np.asarray(u), np.asarray(v)
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.dtype.kind in "biufc":
        return a.tobytes() == b.tobytes()
    return bool(np.array_equal(a, b))


def _same_h5_content(a: str | Path, b: str | Path) -> bool:
    """True when two HDF5 files hold the same groups, datasets and attributes, each
    value bitwise (the files' own bytes may differ: HDF5 lays them out freely)."""
    import h5py

    def same(x, y) -> bool:
        if set(x.attrs) != set(y.attrs) or not all(_same_bits(x.attrs[k], y.attrs[k])
                                                   for k in x.attrs):
            return False
        if isinstance(x, h5py.Dataset):
            return isinstance(y, h5py.Dataset) and _same_bits(x[()], y[()])
        return (isinstance(y, h5py.Group) and set(x) == set(y)
                and all(same(x[k], y[k]) for k in x))

    try:
        with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
            return same(fa, fb)
    except OSError:
        return False


def _h5_readable(path: str | Path) -> bool:
    """True when ``path`` is an HDF5 file whose every dataset can be read."""
    import h5py

    def read_all(g) -> None:
        for v in g.values():
            if isinstance(v, h5py.Dataset):
                v[()]
            else:
                read_all(v)

    try:
        with h5py.File(path, "r") as f:
            read_all(f)
        return True
    except OSError:
        return False


def _reuse(input_path: str | Path, reuse: Sequence[str | Path], out_path: str | Path,
           what: str) -> bool:
    """``reuse`` = (an earlier job's input, that job's output), of the same stage with
    the same settings (the rule passes them: the last active round's files for the
    primary measure). When this job's input holds the same content as the earlier
    input, its output would be the earlier output bit for bit (every stage is
    deterministic): that file is copied to ``out_path`` and True returned."""
    import shutil

    if not reuse:
        return False
    if len(reuse) != 2:
        raise ValueError(f"reuse: expected (earlier input, earlier output), got {list(reuse)}")
    earlier_in, earlier_out = (Path(p) for p in reuse)
    if not _h5_readable(earlier_out):  # missing or damaged: compute
        return False
    if not _same_h5_content(input_path, earlier_in):
        return False
    with atomic_path(out_path, suffix=Path(out_path).suffix) as tmp:
        shutil.copyfile(earlier_out, tmp)
    log.info("%s: input '%s' is the same as '%s': its output '%s' is reused", what,
             input_path, earlier_in, earlier_out)
    return True


# ---------------------------------------------------------------------------- train
def _space(parameters: Sequence[Mapping[str, Any]]):
    from bayescalib.inference.parameters import ParameterSpace

    return ParameterSpace.from_config(parameters)


def train_surrogate(training_path: str | Path, surrogate: Mapping[str, Any],
          parameters: Sequence[Mapping[str, Any]], out_path: str | Path, *,
          reuse: Sequence[str | Path] = (), previous: str | Path | None = None,
          threads: int = 1) -> None:
    """Fit the GP surrogate on the training points (failed runs left out).

    ``previous``: the surrogate file of the previous active round. Its discrete choices
    (kernel, output, inputs, frame) are refitted instead of searched again until the
    training set has grown by ``surrogate.reselect_growth`` since their last full search,
    or until it mispredicts the new values by more than ``surrogate.reselect_error``
    (:func:`bayescalib.inference.gp.selection.fit_round`). None (round 0, a fixed design,
    the study's final surrogate): a full search.

    ``threads``: the job's granted cores; a full search fits its candidates on that many
    processes (the same surrogate, bit for bit).

    ``reuse``: (training table, surrogate) of an earlier fit with the same settings
    (the last active round's); when the training table holds the same content and that
    surrogate searched the discrete choices in full, it is copied instead of fitted again
    (:func:`_reuse`). A round's refit is not reused: the study's surrogate is a full
    search."""
    from bayescalib.inference.gp import fit_round

    if reuse and not _full_search(reuse[-1]):
        log.info("train_surrogate: '%s' refitted the previous round's choices: the "
                 "discrete choices are searched in full for the study's surrogate", reuse[-1])
    elif _reuse(training_path, reuse, out_path, "train_surrogate"):
        return
    tab = read_stage_file(training_path, "training table")
    train_mask = tab["is_train"].astype(bool)
    X, L = _loglik_training_set(tab)
    finite = np.isfinite(L)
    space = _space(parameters)
    bound = loglik_bound(tab, train_mask)
    if surrogate["target"] == "outputs":
        _train_emulator(tab, train_mask, surrogate, space, bound, training_path, out_path)
        return
    prev = None if previous is None else read_stage_file(previous, "surrogate", device="cpu")
    try:
        gp = fit_round(X, L, dict(surrogate), space.bounds, bound=bound, previous=prev,
                       threads=threads)
    except (RuntimeError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        Lf = L[finite]
        raise PipelineError(
            f"the GP surrogate cannot be fitted to the {int(finite.sum())} log-likelihood "
            f"values (range {Lf.min():.6g} to {Lf.max():.6g}): {type(exc).__name__}: {exc}. "
            "Try more surrogate.restarts (now "
            f"{surrogate['restarts']}), the other surrogate.optimizer (now "
            f"'{surrogate['optimizer']}'), a larger surrogate.nugget_factor (now "
            f"{surrogate['nugget_factor']:g}) or surrogate.nugget_floor (now "
            f"{surrogate['nugget_floor']:g}; surrogate.nugget is '{surrogate['nugget']}'), "
            "or a larger likelihood.sigma_n2 if the values "
            "are extreme."
        ) from None
    gp.save(out_path)
    log.info("GP surrogate on %d points (%d excluded, %d of them marking where the model "
             "cannot be solved), choices %s (%s): %s", gp.n_train, gp.n_excluded,
             gp.n_failed, gp.selection, gp.selection_reason or "reason not recorded",
             gp.hyperparameters)


def _loglik_training_set(tab: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The inputs and log-likelihoods the GP surrogate is fitted to: the training
    points of the table (``is_train``), a failure for the machine's sake (no value and
    no infeasible region, :mod:`bayescalib.inference.feasibility`) as NaN, an infeasible
    point's -inf kept. Refuses a table with fewer than 3 finite values or with repeated
    points. The study's surrogate (:func:`train_surrogate`) and the GP convergence study
    (:func:`convergence`) fit these, the latter their prefixes."""
    train_mask = tab["is_train"].astype(bool)
    X, L = tab["X"][train_mask], tab["loglik"][train_mask]
    finite = np.isfinite(L)
    if finite.sum() == 0:
        reasons = sorted({r for r, ok in zip(tab["reason"], train_mask, strict=True) if ok and r})
        raise PipelineError(
            f"all {len(L)} design points failed or have a log-likelihood of -inf, so no "
            "surrogate can be trained. Reasons seen: "
            + ("; ".join(reasons[:5]) or "none recorded")
            + ". Check the forward model settings, the parameter bounds, and sigma_n."
        )
    if finite.sum() < 3:
        raise PipelineError(
            f"only {int(finite.sum())} of {len(L)} design points succeeded; at least 3 are "
            "needed to train the surrogate: increase design.n_train or narrow the bounds"
        )
    _check_distinct(X, finite, tab["names"])
    from bayescalib.inference.feasibility import marks_infeasible

    reasons = [r for r, use in zip(tab["reason"], train_mask, strict=True) if use]
    # a failure for the machine's sake: no value and no infeasible region (feasibility)
    return X, np.where(~finite & ~marks_infeasible(finite, reasons), np.nan, L)


def _train_emulator(tab: Mapping[str, Any], use: np.ndarray, surrogate: Mapping[str, Any],
                    space, bound: float | None, training_path: str | Path,
                    out_path: str | Path) -> None:
    """``surrogate.target: outputs``: the emulator of the residual vectors and the
    likelihood computed from it (:mod:`bayescalib.inference.emulator`)."""
    from bayescalib.inference.emulator import EmulatedLikelihood, fit_output_emulator

    R = np.asarray(tab["residuals"], float)[use]
    if R.shape[1] == 0:
        raise PipelineError(
            f"surrogate.target is 'outputs' but the training table '{training_path}' holds no "
            "residual vectors (it was gathered before they were recorded): delete it and "
            "the discrepancy records of this measure, then rerun (the solves are kept)")
    if bound is None:
        raise PipelineError(
            f"surrogate.target is 'outputs' but the training table '{training_path}' records "
            "no likelihood bound: gather it again")
    opts = surrogate["outputs"]
    from bayescalib.inference.feasibility import marks_infeasible

    marks = marks_infeasible(np.all(np.isfinite(R), axis=1),
                             [r for r, u in zip(tab["reason"], use, strict=True) if u])
    try:
        em = fit_output_emulator(tab["X"][use], R, space.bounds, failed=marks,
                                 energy_tol=opts["energy_tol"],
                                 max_components=opts["max_components"], kernel=opts["kernel"],
                                 restarts=surrogate["restarts"], seed=surrogate["seed"],
                                 inputs=surrogate["inputs"], nugget_floor=opts["nugget_floor"])
    except (RuntimeError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        raise PipelineError(
            f"the output emulator cannot be fitted to the {int(np.isfinite(R).all(1).sum())} "
            f"residual vectors of '{training_path}' ({R.shape[1]} outputs): "
            f"{type(exc).__name__}: {exc}. Try more surrogate.restarts (now "
            f"{surrogate['restarts']}) or a larger surrogate.outputs.nugget_floor (now "
            f"{opts['nugget_floor']:g}).") from None
    lik = EmulatedLikelihood(em, np.zeros(R.shape[1]), offset=bound)
    lik.save(out_path)
    log.info("output emulator on %d points (%d excluded): %d of %d outputs' principal "
             "directions, discarded %.3g (noise units^2 per point), log inputs %s",
             lik.n_train, lik.n_excluded, em.n_components, R.shape[1], em.discarded,
             em.log_inputs)


def _full_search(surrogate_path: str | Path) -> bool:
    """False when the surrogate file records a refit of an earlier round's discrete
    choices (:func:`bayescalib.inference.gp.selection.fit_round`); True otherwise (a full
    search, a file written before the record, or one that cannot be read: then
    :func:`_reuse` decides)."""
    import h5py

    try:
        with h5py.File(surrogate_path, "r") as f:
            value = f.attrs.get("selection", "search")
    except OSError:
        return True
    return (value.decode() if isinstance(value, bytes) else str(value)) != "refit"


def loglik_bound(tab: Mapping[str, Any], use: np.ndarray | None = None) -> float | None:
    """Upper bound of the log-likelihood over the training table's points (the
    largest per-point bound), or None when the table has none (older tables)."""
    b = np.asarray(tab["bound"], float)
    if use is not None:
        b = b[np.asarray(use, bool)]
    b = b[np.isfinite(b)]
    return float(b.max()) if b.size else None


def _check_distinct(X: np.ndarray, use: np.ndarray, names: Sequence[str]) -> None:
    """Refuse repeated design points: a Sobol design never repeats one, so a repeat
    means run records that do not belong to this design."""
    idx = np.flatnonzero(use)
    _, inverse, counts = np.unique(X[idx], axis=0, return_inverse=True, return_counts=True)
    if np.all(counts == 1):
        return
    k = int(np.flatnonzero(counts > 1)[0])
    pts = idx[np.flatnonzero(inverse.ravel() == k)]
    values = ", ".join(f"{n}={v:g}" for n, v in zip(names, X[pts[0]], strict=False))
    raise PipelineError(
        f"design points {', '.join(map(str, pts.tolist()))} have the same parameter values "
        f"({values}); {int((counts - 1).sum())} repeated point(s) in all. A Sobol design "
        "never repeats a point, so these run records do not belong to the design: delete "
        "the results/<study>/runs folder (or the repeated records) and rerun."
    )


def convergence(training_path: str | Path, surrogate: Mapping[str, Any],
                parameters: Sequence[Mapping[str, Any]], n_train_list: Sequence[int],
                out_path: str | Path) -> dict[str, Any]:
    """GP convergence over n_train against the held-out Sobol points (paper Sec. 4.3).

    The GP of each n is the study's surrogate fitted to the first n training points: the
    values :func:`train_surrogate` fits (:func:`_loglik_training_set`), the likelihood's
    bound of the whole table, and :func:`bayescalib.inference.gp.selection.fit_from_config`
    with the study's ``surrogate`` section (kernel, output, ard, frame, inputs, mean,
    nugget and the optimizer's settings, searched as the study's surrogate searches
    them); only the training size varies. At the full training set it is the study's
    surrogate. ``surrogate`` in the record: each n's hyperparameters."""
    from bayescalib.inference.convergence import convergence_study
    from bayescalib.inference.gp import fit_from_config

    tab = read_stage_file(training_path, "training table")
    tr = tab["is_train"].astype(bool)
    X, L = _loglik_training_set(tab)
    bounds = _space(parameters).bounds
    bound = loglik_bound(tab, tr)
    settings = dict(surrogate)
    res = convergence_study(
        X, L, tab["X"][~tr], tab["loglik"][~tr], n_train_list=list(n_train_list),
        fit=lambda Xn, Ln: fit_from_config(Xn, Ln, settings, bounds, bound=bound))
    write_json(out_path, res)
    return res


# ------------------------------------------------------------------------------ smc
def smc(surrogate_path: str | Path, smc_cfg: Mapping[str, Any],
        parameters: Sequence[Mapping[str, Any]], out_path: str | Path, *,
        threads: int = 1, reuse: Sequence[str | Path] = ()) -> None:
    """Run SMC with adaptive tempering on the GP mean of the log-likelihood.

    ``threads`` > 1 evaluates the surrogate's chunks of particles on that many threads
    (:attr:`GPSurrogate.threads`): the same chunks, each computed alone, so the
    particles are bitwise those of one thread. ``reuse``: (surrogate, particles) of an
    earlier SMC with the same settings (the last active round's); when the surrogate
    holds the same content, those particles are copied instead of sampled again
    (:func:`_reuse`; their history's ``time_s`` is the earlier run's).
    """
    from bayescalib.inference.posterior import write_particles_h5
    from bayescalib.inference.smc import smc_from_config

    if _reuse(surrogate_path, reuse, out_path, "smc"):
        return
    gp = read_stage_file(surrogate_path, "surrogate")
    gp.threads = max(1, int(threads))
    space = _space(parameters)

    result = smc_from_config(gp.loglik, space, smc_cfg)
    write_particles_h5(out_path, result, space)
    log.info("SMC done: %d steps, log evidence %.4f", result.n_steps, result.log_evidence)


def acquire(round_index: int, training_path: str | Path, surrogate_path: str | Path,
            particles_path: str | Path, previous_path: str | Path | None,
            active: Mapping[str, Any], check: Mapping[str, Any],
            parameters: Sequence[Mapping[str, Any]], out_path: str | Path) -> dict[str, Any]:
    """Active design, end of round ``round_index``: trust check, posterior change,
    stop rule and the next batch (:func:`bayescalib.inference.active.acquire_round`), as JSON."""
    from bayescalib.inference.active import acquire_round
    from bayescalib.inference.emulator import EmulatedLikelihood

    tab = read_stage_file(training_path, "training table")
    gp = read_stage_file(surrogate_path, "surrogate")
    res = read_stage_file(particles_path, "SMC particle file")
    previous = None if previous_path is None else \
        read_stage_file(previous_path, "active round record")
    try:
        rec = acquire_round(int(round_index), tab["X"], tab["loglik"], gp, res.particles,
                            res.weights, res.log_evidence, _space(parameters), active, previous,
                            check,
                            acquisition="draws" if isinstance(gp, EmulatedLikelihood) else "select")
    except ValueError as exc:
        raise PipelineError(f"active round {round_index}: {exc}. Delete results/<study>/active "
                            "and the runs of the active rounds, then rerun.") from None
    rec["surrogate_output"] = gp.hyperparameters["output"]
    write_json(out_path, rec)
    log.info("active round %d (%d solves): %s", round_index, rec["n_solves"], rec["reason"])
    return rec


def marginalize(particles_path: str | Path, surrogate_path: str | Path,
                posterior_cfg: Mapping[str, Any], parameters: Sequence[Mapping[str, Any]],
                seed: int, out_json: str | Path, out_netcdf: str | Path) -> dict[str, Any]:
    """Posterior summaries (JSON) and the ArviZ NetCDF export."""
    from bayescalib.inference.posterior import summarize, write_netcdf

    gp = read_stage_file(surrogate_path, "surrogate")
    space = _space(parameters)
    result = read_stage_file(particles_path, "SMC particle file")
    summary = summarize(result, space, loglik=gp.loglik,
                        map_bins=posterior_cfg.get("map_bins"),
                        levels=tuple(posterior_cfg["levels"]))
    write_json(out_json, summary)
    write_netcdf(out_netcdf, result, space, np.random.default_rng(seed),
                 posterior_cfg["n_draws"])
    return summary


# -------------------------------------------------------------------------- summary
def summary(study_name: str, parameters: Sequence[Mapping[str, Any]], measures: Sequence[str],
            posterior_paths: Sequence[str | Path], training_paths: Sequence[str | Path],
            particles_paths: Sequence[str | Path], figures: Mapping[str, Any],
            out_path: str | Path, *, extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Write ``summary.json``: the study's results in the user's units.

    The first measure is the calibration measure: its results are the top-level
    ``map``, ``posterior_mean``, ``posterior_cov`` and ``log_evidence``; every
    measure's results are also listed under ``measures``. ``fit`` is the absolute
    check of the calibration measure's best solve against the likelihood's noise
    model (:func:`bayescalib.inference.likelihood.fit_check`; per measure as well).
    """
    from bayescalib.inference.likelihood import fit_check

    names = [p["name"] for p in parameters]
    targets = [p["target"] for p in parameters]
    per_measure: dict[str, Any] = {}
    posts: dict[str, Any] = {}
    failed_runs: list[dict[str, Any]] = []
    for m, pp, tp, parts in zip(measures, posterior_paths, training_paths, particles_paths,
                                strict=True):
        post = posts[m] = read_stage_file(pp, "posterior summary")
        tab = read_stage_file(tp, "training table")
        res = read_stage_file(parts, "SMC particle file")
        tr = tab["is_train"].astype(bool)
        # one line per measure; the full posterior analysis is in its posterior.json
        per_measure[m] = {
            "posterior_json": str(pp),
            "posterior_mean": post["mean"], "posterior_sd": post["std"], "map": post["map"],
            "log_evidence": float(res.log_evidence),
            "n_smc_steps": int(res.n_steps),
            "n_train": int(tr.sum()),
            "n_failed": int((tab["status"][tr] == 0).sum()),
            "fit": fit_check(tab["loglik"][tr], tab["bound"][tr], tab["n_measurements"][tr]),
        }
        if m == measures[0]:
            from bayescalib.inference.feasibility import marks_infeasible

            marks = marks_infeasible(tab["status"] != 0, tab["reason"]) & tr
            failed_runs = [
                {"point": int(i), "parameters": dict(zip(names, map(float, tab["X"][i]),
                                                         strict=True)),
                 "reason": tab["reason"][i] or "no reason recorded",
                 "marks_infeasible": bool(marks[i])}
                for i in np.flatnonzero(tab["status"] == 0)]
    primary = per_measure[measures[0]]
    post = posts[measures[0]]
    truth = {p["name"]: p.get("ground_truth") for p in parameters}
    lap = post.get("laplace") or {}
    out = {
        "study": study_name,
        "measure": measures[0],
        "parameters": [
            {"name": n, "unit": p["unit"], "target": t,
             "uncertain": bool(p.get("uncertain")), "bounds": p.get("bounds")}
            for n, t, p in zip(names, targets, parameters, strict=True)
        ],
        "units": {"length": "mm", **{p["name"]: p["unit"] for p in parameters}},
        "map": post["map"],
        "map_marginal": post.get("map_marginal"),
        "posterior_mean": post["mean"],
        "posterior_sd": post["std"],
        "posterior_cov": post["cov"],
        "credible_interval_type": "equal-tailed (weighted quantiles of the SMC particles)",
        "credible_intervals": post.get("intervals"),
        "laplace": {"names": lap.get("names"), "mean": lap.get("mean"), "cov": lap.get("cov"),
                    "positive_definite": lap.get("positive_definite"),
                    "hessian_convention": lap.get("hessian_convention")} if lap else None,
        "log_evidence": primary["log_evidence"],
        "n_train": primary["n_train"],
        "n_failed": primary["n_failed"],
        "n_failed_infeasible": sum(r["marks_infeasible"] for r in failed_runs),
        "failed_runs": failed_runs,
        # only where every parameter has one (real data: no ground truth, no key)
        **({"ground_truth": truth} if all(v is not None for v in truth.values()) else {}),
        "converged": (extra or {}).get("design", {}).get("converged"),
        "fit": primary["fit"],
        "measures": per_measure,
        "figures": dict(figures),
    }
    if extra:
        out.update(extra)
    write_json(out_path, out)
    log.info("summary of %s (%s) -> %s", study_name, ", ".join(names), out_path)
    return out


def posterior_check(sample_runs: Sequence[str | Path], obs_path: str | Path, measure_name: str,
                    measure: Mapping[str, Any], likelihood: Mapping[str, Any],
                    surrogate_path: str | Path, parameters: Sequence[Mapping[str, Any]],
                    check: Mapping[str, Any], out_path: str | Path,
                    particles_path: str | Path) -> dict[str, Any]:
    """The final posterior checked by importance sampling with real solves.

    ``sample_runs`` are the forward solves of equally weighted draws of the final
    posterior (the ``predictive_solve`` jobs, resampled from ``particles_path``); each
    gets its discrepancy and real log-likelihood (records under ``<out>.draws/``), the
    surrogate's log-likelihood at the same parameters is the one the SMC sampled, and
    :func:`bayescalib.inference.importance.importance_check` compares the two
    posteriors, and asks whether the draws represent the weighted particles' mean and sd
    (a tail the draws missed is not checked by them). Writes ``out_path`` (JSON: the check's numbers keyed by parameter name,
    in the user's units) and returns it.
    """
    from bayescalib.inference.active import posterior_moments
    from bayescalib.inference.importance import importance_check

    names = [p["name"] for p in parameters]
    targets = [p["target"] for p in parameters]
    draws_dir = Path(str(out_path) + ".draws")
    X, L = [], []
    for k, rp in enumerate(sample_runs):
        rec = discrepancy(rp, obs_path, measure_name, measure, likelihood,
                          draws_dir / f"{k}.json")
        X.append([float(rec["parameters"][t]) for t in targets])
        L.append(-math.inf if rec.get("loglik") is None else float(rec["loglik"]))
    X_arr, L_arr = np.asarray(X, float).reshape(-1, len(names)), np.asarray(L, float)
    gp = read_stage_file(surrogate_path, "surrogate")
    mu = gp.predict(X_arr)
    smc = read_stage_file(particles_path, "SMC particle file")
    moments = posterior_moments(smc.particles, smc.weights)
    res = importance_check(X_arr, L_arr, mu, min_ess_fraction=check["min_ess_fraction"],
                           shift_tol=check["shift_tol"], sd_tol=check["sd_tol"],
                           max_log_weight_sd=check["max_log_weight_sd"],
                           max_failed_fraction=check["max_failed_fraction"],
                           posterior_mean=moments["mean"], posterior_sd=moments["sd"])
    out = {"measure": measure_name, "names": names, **res,
           "draws": [{"parameters": dict(zip(names, x, strict=True)),
                      "loglik": None if not math.isfinite(ll) else ll,
                      "surrogate_loglik": float(m)}
                     for x, ll, m in zip(X_arr.tolist(), L_arr.tolist(), mu.tolist(),
                                         strict=True)]}
    for key in ("mean_q", "sd_q", "mean_is", "sd_is", "shift_sd", "shift_se", "sd_ratio",
                "draws_shift_sd", "draws_sd_ratio"):
        if key in out:
            out[key] = dict(zip(names, out[key], strict=True))
    write_json(out_path, out)
    log.info("posterior check (%s): %s", measure_name, res["words"])
    return out


def posterior_check_summary(path: str | Path) -> dict[str, Any]:
    """The ``posterior_check`` block of summary.json: the check's file without its
    per-draw records (which stay in the file, named here)."""
    rec = read_stage_file(path, "posterior check")
    return {"file": str(path), **{k: v for k, v in rec.items() if k != "draws"}}


def round_check_summary(acquire_paths: Sequence[str | Path]) -> dict[str, Any] | None:
    """The ``posterior_check`` block of summary.json for an active design: the last
    check round's verdict (:func:`bayescalib.inference.active.round_check`, ``round``:
    the round whose posterior was checked), with the record it is in; None when the
    rounds ran no check."""
    for path in reversed(list(acquire_paths)):
        rec = read_stage_file(path, "active round record")
        if rec.get("posterior_check") is not None:
            return {"file": str(path), **rec["posterior_check"]}
    return None


def design_summary(strategy: str, acquire_paths: Sequence[str | Path],
                   n_solves: int, max_solves: int | None = None,
                   check_draws: int | None = None) -> dict[str, Any]:
    """The ``design`` block of summary.json: how the solves were chosen and whether
    the calibration converged (active design), with the per-round history.

    A fixed design has no convergence check: ``converged`` is None and the reason
    says so. ``max_solves`` (design.active.max_solves) and ``check_draws`` (the size of
    a check round) are the budget the verdict speaks of (active design only).
    """
    from bayescalib.inference.active import history_table

    if strategy != "active":
        return {"strategy": strategy, "n_solves": int(n_solves), "converged": None,
                "reason": "fixed design (design.strategy: fixed): the surrogate was not "
                          "checked against solves placed where the posterior lives, so "
                          "nothing says whether this posterior has converged",
                "rounds": []}
    rounds = [read_stage_file(p, "active round record") for p in acquire_paths]
    last = rounds[-1]
    return {"strategy": "active", "n_solves": int(last["n_solves"]),
            "n_failed": int(last["n_failed"]), "n_rounds": len(rounds),
            "converged": bool(last["converged"]), "reason": last["reason"],
            "max_solves": None if max_solves is None else int(max_solves),
            "check_draws": None if check_draws is None else int(check_draws),
            "surrogate_output": last.get("surrogate_output"),
            "rounds": history_table(rounds)}


def run_line(summary_json: Mapping[str, Any]) -> str:
    """One plain line for the end of a run: posterior mean +- sd with units, solves used
    and failed. Whether it converged, and whether the best fit is within the noise, is
    the verdict that follows it (:func:`bayescalib.stages.verdict.verdict`)."""
    names = [p["name"] for p in summary_json["parameters"]]
    units = {p["name"]: p.get("unit", "-") for p in summary_json["parameters"]}
    cov = np.asarray(summary_json["posterior_cov"], float)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    mean = summary_json["posterior_mean"]
    parts = []
    for k, name in enumerate(names):
        unit = "" if units[name] in ("-", "") else f" {units[name]}"
        parts.append(f"{name} = {mean[name]:.4g} +- {sd[k]:.2g}{unit}")
    design = summary_json.get("design") or {}
    n_solves = design.get("n_solves", summary_json.get("n_train"))
    n_failed = design.get("n_failed", summary_json.get("n_failed"))
    n_region = summary_json.get("n_failed_infeasible") or 0
    region = (f" ({n_region} mark where the model cannot be solved: the posterior excludes "
              f"their neighbourhood)") if n_region else ""
    return (f"bayescalib {summary_json['study']}: {', '.join(parts)}; "
            f"{n_solves} solves, {n_failed} failed{region}")


def _front_figure(s: Mapping[str, Any]) -> str | None:
    """The figure of the posterior for the report's front page: the primary measure's
    joint posterior (the marginals with one parameter), as a PNG that exists; None
    when there is none (PNG not among plots.formats, or not yet drawn)."""
    figures = s.get("figures") or {}
    for family in ("joint", "marginals"):
        for f in figures.get(f"{s.get('measure')}/{family}") or []:
            if str(f).endswith(".png") and Path(f).is_file():
                return str(f)
    return None


def front_page(summary_path: str | Path, embed_figure: bool = False) -> dict[str, Any] | None:
    """The key numbers of a finished study for the report's front page: the run line,
    the verdict (:func:`bayescalib.stages.verdict.verdict`), the figure of the posterior
    (``figure``: a PNG path, or None; with ``embed_figure``, when a report is made,
    ``figure_uri``: the PNG as a data URI, which the report's self-contained page shows,
    in lines of 76 characters: docutils refuses longer lines, and removes the breaks),
    whether it converged and why in full, and per
    parameter MAP, mean, sd, the 90 % equal-tailed
    interval and, where the study has one (``truth_known``), the ground truth (strings,
    in the user's units). None before the study has a summary.json (or when it cannot
    be read)."""
    path = Path(summary_path)
    if not path.is_file():
        return None
    try:
        s = read_json(path)
    except PipelineError:
        return None

    def fmt(v) -> str:
        return "-" if v is None else f"{float(v):.4g}"

    truth = s.get("ground_truth") or {}
    ci = s.get("credible_intervals") or {}
    rows = []
    for p in s["parameters"]:
        n = p["name"]
        lohi = (ci.get(n) or {}).get("0.9")
        rows.append([n, p.get("unit", "-"), fmt(s["map"].get(n)), fmt(s["posterior_mean"].get(n)),
                     fmt((s.get("posterior_sd") or {}).get(n)),
                     "-" if not lohi else f"[{fmt(lohi[0])}, {fmt(lohi[1])}]"]
                    + ([fmt(truth.get(n))] if truth else []))
    design = s.get("design") or {}
    fit = s.get("fit") or {}
    check = s.get("posterior_check") or {}
    from bayescalib.stages.verdict import verdict

    figure = _front_figure(s)
    uri = None
    if figure is not None and embed_figure:
        import base64

        text = "data:image/png;base64," + base64.b64encode(Path(figure).read_bytes()).decode()
        uri = [text[k:k + 76] for k in range(0, len(text), 76)]
    return {"line": run_line(s), "verdict": verdict(s), "figure": figure, "figure_uri": uri,
            "reason": design.get("reason", ""), "rows": rows,
            "truth_known": bool(truth),
            "converged": design.get("converged"), "measure": s.get("measure"),
            "fit": fit.get("words", ""), "fit_consistent": fit.get("consistent"),
            "check": check.get("words", ""), "check_confirmed": check.get("confirmed")}


def collect_timings(root: str | Path) -> dict[str, Any]:
    """Wall time per stage from Snakemake's benchmark files under ``root/benchmarks``.

    Returns the summed seconds per stage (``solve``, ``discrepancy``, ...) and,
    for solves, the median and count. Stages without benchmark files are absent.
    """
    import csv

    base = Path(root) / "benchmarks"
    out: dict[str, Any] = {}
    if not base.is_dir():
        return out
    for tsv in sorted(base.rglob("*.tsv")):
        stage = tsv.relative_to(base).parts[0]
        stage = stage.removesuffix(".tsv")
        try:
            with open(tsv) as fh:
                rows = list(csv.DictReader(fh, delimiter="\t"))
            seconds = float(rows[-1]["s"])
        except (OSError, KeyError, ValueError, IndexError):
            continue
        out.setdefault(stage, []).append(seconds)
    summary: dict[str, Any] = {}
    for stage, values in out.items():
        summary[stage] = {"total_s": float(np.sum(values)), "median_s": float(np.median(values)),
                          "count": len(values)}
    return summary
