"""Stage ``gather`` (rules ``gather`` and ``gather_round``): the training table of one
measure, every design point's parameters and log-likelihood in one HDF5 file.

:func:`gather_rows` reads each point's run record and discrepancy record into the rows
(also for the in-process rounds of :mod:`bayescalib.stages.chain`); :func:`gather` writes
them (:func:`bayescalib.io.training.write_training`). With each log-likelihood go its
upper bound (:func:`record_bound`, the first term of eq:loglik) and the residual vector
(:func:`record_residuals`, whose half squared norm is the misfit), which the output
emulator is trained on. A run record written for another parameter setup is set aside.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.io.training import write_training
from bayescalib.stages.errors import PipelineError
from bayescalib.stages.files import read_stage_file, set_aside

__all__ = ["gather", "gather_rows", "record_bound", "record_residuals"]


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
            raise set_aside(rp, f"run file '{rp}' has no value for {', '.join(missing)} "
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
