"""The training table: one row per design point of a study and measure (the output of
the ``gather`` stage, the input of ``train_surrogate``, ``smc`` and ``acquire``).

Layout (kind ``training`` of :mod:`bayescalib.io.header`)::

    /X (n, d)  /loglik (n,)  /D (n,)  /status (n,) int8  /is_train (n,) int8
    /bound (n,)  /reason (n,) str  /residuals (n, m)
    attrs: format, format_version, names (JSON list), n_train, n_failed
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.io._atomic_write import atomic_path
from bayescalib.io.header import validate_header, write_header

__all__ = ["read_training", "write_training"]

log = logging.getLogger(__name__)


def write_training(out_path: str | Path, X: np.ndarray, L: np.ndarray, D: np.ndarray,
                   ok: np.ndarray, reasons: Sequence[str], names: Sequence[str],
                   n_train: int, *, bound: np.ndarray | None = None,
                   n_measurements: np.ndarray | None = None,
                   residuals: np.ndarray | None = None) -> None:
    """Write a training table atomically: the design points ``X`` (n, d), their
    log-likelihoods ``L``, discrepancies ``D``, success flags ``ok`` and failure
    ``reasons`` (n,), the parameter ``names``, the number of training rows ``n_train``
    (the rest are held-out test points), each row's likelihood ``bound`` and its
    number of measurements ``n_measurements`` (NaN where unknown), and its residual
    vector in noise units ``residuals`` (n, m) (a row of NaN for a failed solve; m = 0:
    none), whose half squared norm is the misfit: ``loglik = bound - |r|^2 / 2``."""
    import h5py

    n = len(L)
    with atomic_path(out_path, suffix=".h5") as tmp, h5py.File(tmp, "w") as f:
        write_header(f, "training")
        f["X"] = np.asarray(X, dtype=float)
        f["loglik"] = np.asarray(L, dtype=float)
        f["D"] = np.asarray(D, dtype=float)
        f["status"] = np.asarray(ok, dtype=np.int8)
        f["is_train"] = (np.arange(n) < n_train).astype(np.int8)
        f["bound"] = np.full(n, np.nan) if bound is None else np.asarray(bound, dtype=float)
        f["n_measurements"] = np.full(n, np.nan) if n_measurements is None else \
            np.asarray(n_measurements, dtype=float)
        R = np.zeros((n, 0)) if residuals is None else np.asarray(residuals, dtype=float)
        f["residuals"] = R if R.ndim == 2 else R.reshape(n, -1 if R.size else 0)
        f.create_dataset("reason", data=np.array(list(reasons), dtype=object),
                         dtype=h5py.string_dtype())
        f.attrs["names"] = json.dumps(list(names))
        f.attrs["n_train"] = int(n_train)
        f.attrs["n_failed"] = int(n - np.asarray(ok).sum())
    log.info("training table: %d points, %d failed -> %s", n, n - int(np.asarray(ok).sum()),
             out_path)


def read_training(path: str | Path) -> dict[str, Any]:
    """Read a training table written by :func:`write_training` (arrays and attributes)."""
    import h5py

    with h5py.File(path, "r") as f:
        validate_header(f, "training", path)
        out = {k: f[k][...] for k in ("X", "loglik", "D", "status", "is_train")}
        for key in ("bound", "n_measurements"):  # absent from tables of earlier runs
            out[key] = f[key][...] if key in f else np.full(len(out["loglik"]), np.nan)
        # absent from tables of earlier runs: no residual vectors (m = 0)
        out["residuals"] = f["residuals"][...] if "residuals" in f else \
            np.zeros((len(out["loglik"]), 0))
        out["reason"] = [r.decode() if isinstance(r, bytes) else str(r) for r in f["reason"][...]]
        out["names"] = json.loads(f.attrs["names"])
        out["n_train"] = int(f.attrs["n_train"])
        out["n_failed"] = int(f.attrs["n_failed"])
    return out
