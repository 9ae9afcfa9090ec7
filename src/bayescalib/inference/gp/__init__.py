"""Gaussian-process surrogate of the log-likelihood (paper Sec. 3.2 and App. D).

A GP of the log-likelihood L(x) (or of its log-misfit) on unit-box-scaled inputs, with
a fast batched predictor for the SMC. One module per job:

- :mod:`~bayescalib.inference.gp.kernels`: the stationary kernels (eq. prior_gp,
  eq. matern32): :data:`KERNELS`, :func:`kernel_matrix`, :func:`matern32`.
- :mod:`~bayescalib.inference.gp.predictor`: :class:`GPSurrogate`, the fitted surrogate
  and its predictor (eq. posterior_gp; NumPy chunks and threads, or torch on a GPU:
  :func:`gpu_possible`).
- :mod:`~bayescalib.inference.gp.fit`: :func:`fit_gp`, one GP fit by its evidence
  (eq. gploglikeli; GPy), with the fixed or fitted nugget.
- :mod:`~bayescalib.inference.gp.mean`: the prior mean, constant or misfit-shaped
  (quadratic).
- :mod:`~bayescalib.inference.gp.warping`: the output transform, the log-misfit
  g = log(1 + B - L), and the evidence of L of a warped GP.
- :mod:`~bayescalib.inference.gp.inputs`: the input coordinates: log inputs
  (:func:`log_input_offsets`, :func:`warp_inputs`) and the principal-axes frame
  (:func:`principal_frame`).
- :mod:`~bayescalib.inference.gp.selection`: the study's surrogate from its settings:
  the search of the discrete choices by the evidence (:func:`fit_from_config`), the
  per-round refit of an active design (:func:`fit_round`), the ``auto`` settings
  (:func:`resolve_ard`, :func:`resolve_mean`), :func:`search_size`,
  :func:`surrogate_settings`.
- :mod:`~bayescalib.inference.gp.store`: the HDF5 surrogate file
  (:meth:`GPSurrogate.save` / :meth:`GPSurrogate.load`).

The measurements behind the methods and defaults, each with the command that
reproduces it: ``docs/surrogate.md``.
"""

from __future__ import annotations

from bayescalib.inference.gp.fit import fit_gp
from bayescalib.inference.gp.inputs import log_input_offsets, principal_frame, warp_inputs
from bayescalib.inference.gp.kernels import KERNELS, kernel_matrix, matern32
from bayescalib.inference.gp.predictor import GPSurrogate, gpu_possible
from bayescalib.inference.gp.selection import (
    fit_from_config,
    fit_round,
    resolve_ard,
    resolve_mean,
    search_size,
    surrogate_settings,
)

__all__ = ["KERNELS", "GPSurrogate", "fit_from_config", "fit_gp", "fit_round", "gpu_possible",
           "kernel_matrix", "log_input_offsets", "matern32", "principal_frame", "resolve_ard",
           "resolve_mean", "search_size", "surrogate_settings", "warp_inputs"]
