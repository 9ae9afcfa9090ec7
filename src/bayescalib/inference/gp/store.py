"""The GP surrogate file: HDF5 layout, writing and reading.

A surrogate file (:func:`save`, atomically) holds the file header of the kind
``"surrogate"`` (:mod:`bayescalib.io.header`: layout version 3, version-2 files still
read) and the surrogate's group (:func:`write_group`): the training data and input
scaling (``X_train``, ``y_train``, ``input_shift``, ``input_scale``, and
``input_rotation`` / ``input_log_offset`` when the GP has a frame or log inputs), the
factors of the predictor (``chol``, gzip-compressed, and ``alpha``), the kernel's and
the mean's hyperparameters (``lengthscale``; attributes ``kernel`` (the GPy class name),
``variance``, ``nugget``, ``mean_const``, ``mean_function``, and ``mean_center`` /
``mean_factor`` / ``mean_misfit_min`` / ``mean_top`` for the quadratic mean), the output
transform (``bound``, NaN when unknown, and ``warp``) and metadata (``ard``,
``n_excluded``, ``log_marginal_likelihood``, ``optimizer``, ``restarts``, ``selection``,
``selection_n``, ``selection_reason``, ``selection_error``, ``nugget_mode``, and
``X_failed`` when solves failed). An output emulator
stores one such group per output coordinate (:mod:`bayescalib.inference.emulator`).

:func:`read_group` rebuilds the :class:`~bayescalib.inference.gp.predictor.GPSurrogate`
from the stored factors, so its predictions are reproduced exactly. Attributes added
within a layout version are read with the value that files written before them meant:
no ``kernel``, Matérn 3/2; no ``bound``, no warping (version 1); no ``mean_function``, the
constant mean (version 2); no ``selection``, a full search with n unknown; no
``selection_reason`` / ``selection_error``, the reason not known (``""``, NaN); no
``nugget_mode``, the fixed nugget; no ``X_failed``, no failed points known.
The header's ``format`` attribute (``bayescalib.GPSurrogate``) is a label of the kind,
not an import path; no module path is stored, so the file does not depend on where the
code lives.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from bayescalib.inference.gp.kernels import KERNELS
from bayescalib.inference.gp.predictor import _SEARCH, GPSurrogate
from bayescalib.io._atomic_write import atomic_path
from bayescalib.io.header import validate_header, write_header

__all__ = ["load", "read_group", "save", "write_group"]


def _kernel_name(stored: str) -> str:
    for name, (_, gpy_name) in KERNELS.items():
        if gpy_name == stored:
            return name
    raise ValueError(f"unknown kernel {stored!r} in a surrogate file")


def _plain_str(value: Any) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _bound_attr(value: Any) -> float | None:
    """The stored bound attribute (NaN or absent: no warping; format version 1)."""
    if value is None or not math.isfinite(float(value)):
        return None
    return float(value)


def save(gp: GPSurrogate, path: str | Path) -> None:
    """Write the surrogate ``gp`` to HDF5 (atomically): the file header, then its group
    (:func:`write_group`): data, scaling, hyperparameters, factors."""
    import h5py

    with atomic_path(path, suffix=".h5") as tmp, h5py.File(tmp, "w") as f:
        write_header(f, "surrogate")
        write_group(gp, f)


def write_group(gp: GPSurrogate, f) -> None:
    """Write the data of the surrogate ``gp`` into the open h5py file or group ``f`` (the
    layout of :func:`save`, without the file header: an emulator stores one per output
    coordinate, :mod:`bayescalib.inference.emulator`)."""
    f.attrs["kernel"] = KERNELS[gp.kernel][1]
    f.create_dataset("X_train", data=gp.X_train)
    f.create_dataset("y_train", data=gp.y_train)
    f.create_dataset("input_shift", data=gp.shift)
    f.create_dataset("input_scale", data=gp.scale)
    f.create_dataset("lengthscale", data=gp.lengthscale)
    f.create_dataset("chol", data=gp.chol, compression="gzip")
    f.create_dataset("alpha", data=gp.alpha)
    for k in ("mean_const", "nugget", "variance", "log_marginal_likelihood"):
        f.attrs[k] = float(getattr(gp, k))
    f.attrs["ard"] = bool(gp.ard)
    f.attrs["n_excluded"] = int(gp.n_excluded)
    f.attrs["optimizer"] = gp.optimizer
    f.attrs["restarts"] = int(gp.restarts)
    f.attrs["bound"] = float("nan") if gp.bound is None else float(gp.bound)
    f.attrs["warp"] = bool(gp.warp)
    if gp.rotation is not None:
        f.create_dataset("input_rotation", data=gp.rotation)
    if gp.log_offset is not None:
        f.create_dataset("input_log_offset", data=gp.log_offset)
    f.attrs["mean_function"] = gp.mean_function
    if gp.mean_function == "quadratic":
        f.create_dataset("mean_center", data=gp.mean_center)
        f.create_dataset("mean_factor", data=gp.mean_factor)
        f.attrs["mean_misfit_min"] = float(gp.mean_misfit_min)
        f.attrs["mean_top"] = float(gp.mean_top)
    # added within format version 3 (readers ignore unknown attributes)
    f.attrs["selection"] = gp.selection
    f.attrs["selection_n"] = int(gp.selection_n)
    f.attrs["selection_reason"] = gp.selection_reason
    f.attrs["selection_error"] = float(gp.selection_error)
    f.attrs["nugget_mode"] = "fit" if gp.nugget_fitted else "fixed"
    if gp.X_failed is not None:
        f.create_dataset("X_failed", data=gp.X_failed)


def load(path: str | Path, device: str = "auto") -> GPSurrogate:
    """Read a surrogate written by :func:`save`; predictions are reproduced exactly."""
    import h5py

    with h5py.File(path, "r") as f:
        validate_header(f, "surrogate", path)
        return read_group(f, device=device)


def read_group(f, device: str = "auto") -> GPSurrogate:
    """Read a surrogate from the open h5py file or group ``f`` (:func:`write_group`)."""
    return GPSurrogate(
        X_train=f["X_train"][()],
        y_train=f["y_train"][()],
        shift=f["input_shift"][()],
        scale=f["input_scale"][()],
        mean_const=float(f.attrs["mean_const"]),
        nugget=float(f.attrs["nugget"]),
        variance=float(f.attrs["variance"]),
        lengthscale=f["lengthscale"][()],
        ard=bool(f.attrs["ard"]),
        n_excluded=int(f.attrs["n_excluded"]),
        log_marginal_likelihood=float(f.attrs["log_marginal_likelihood"]),
        optimizer=str(f.attrs["optimizer"]),
        restarts=int(f.attrs["restarts"]),
        chol=f["chol"][()],
        alpha=f["alpha"][()],
        device=device,
        bound=_bound_attr(f.attrs.get("bound")),
        warp=bool(f.attrs.get("warp", False)),
        kernel=_kernel_name(str(f.attrs.get("kernel", "Matern32"))),
        rotation=f["input_rotation"][()] if "input_rotation" in f else None,
        log_offset=f["input_log_offset"][()] if "input_log_offset" in f else None,
        # format version 2 (before the quadratic mean): a constant mean
        mean_function=_plain_str(f.attrs.get("mean_function", "constant")),
        mean_center=f["mean_center"][()] if "mean_center" in f else None,
        mean_factor=f["mean_factor"][()] if "mean_factor" in f else None,
        mean_misfit_min=float(f.attrs.get("mean_misfit_min", float("nan"))),
        mean_top=float(f.attrs.get("mean_top", float("nan"))),
        # files written before the selection was recorded: a full search, n unknown
        selection=_plain_str(f.attrs.get("selection", _SEARCH)),
        selection_n=int(f.attrs.get("selection_n", -1)),
        # files written before the reason was recorded: not known
        selection_reason=_plain_str(f.attrs.get("selection_reason", "")),
        selection_error=float(f.attrs.get("selection_error", float("nan"))),
        # files written before the fitted nugget: the fixed rule
        nugget_fitted=_plain_str(f.attrs.get("nugget_mode", "fixed")) == "fit",
        # files written before the failed points were kept: none known
        X_failed=f["X_failed"][()] if "X_failed" in f else None,
    )
