"""Gaussian-process surrogate of the log-likelihood (paper Sec. 3.2 and App. D).

Model (eq. prior_gp, eq. matern32)
    L(x) ~ GP(m, k),   k(x, x') = s^2 (1 + sqrt(3) r) exp(-sqrt(3) r),
    r = || (u - u') / l ||_2,

on *unit-box-scaled* inputs u = (x - lo) / (hi - lo): each input is mapped
to [0, 1] by the design box (``bounds``; when not given, by the min/max of the
training inputs). ``ard=False`` uses one length scale l for all scaled inputs
(the paper's 2D case); ``ard=True`` one per input (the paper's 6D/7D case).

Principal-axes frame (``rotation``; ``surrogate.frame``)
    An ARD kernel's length scales follow the input coordinates. A posterior with
    strongly correlated directions (a ridge such as E2 with nu2 and the inflow in
    the heterogeneous study) is then poorly described by axis-aligned length
    scales. With ``rotation = V`` (orthogonal, (d, d)) the GP's inputs are
    u V: the box-scaled inputs in the principal axes of the high-likelihood
    training points (:func:`principal_frame`; a tempered-likelihood-weighted
    covariance, a rough posterior covariance), so that the length scales follow
    the posterior's principal axes -- the input whitening of Bayesian-optimization
    and VBMC practice, reduced to its rotation (the ARD scales absorb the rest).
    Measured on an ideal design (``benchmarks/gp_rotation.py``, Matérn 3/2, two
    seeds): the median error of the log-likelihood in the posterior falls from
    0.47-0.58 to 0.023-0.026 nats on ``sloppy4d`` and from 0.99-1.10 to 0.60-0.70
    nats on ``hetero7d``. ``fit_from_config`` fits both frames and keeps the
    larger evidence (``frame: auto``). A stationary kernel is translation
    invariant, so the frame needs no centre; an isotropic kernel is rotation
    invariant, so it keeps the axes.

Log inputs (``log_offset``; ``surrogate.inputs``)
    Moduli and rates act multiplicatively: the FSI deformation depends on the
    inflow rate over E, so the high-likelihood set of the uncertain-inflow study is a
    wedge E ~ V_in whose width in E grows with E. A stationary kernel has one length
    scale for the whole wedge and misses its narrow end (low E, low V_in). In log
    coordinates the wedge is a band of constant width. With ``log_offset = c``
    ((d,), NaN for a linear input) input k enters as log(x_k + c_k) before the box
    scaling (the bounds are mapped the same way, so u stays in [0, 1]): the log
    input warping of Bayesian optimization for positive scale parameters (Snoek et
    al. 2014 warp every input with a learned Beta CDF; here the one fixed warping
    that suits scale parameters). :func:`log_input_offsets` gives
    c = max(0, 0.05 hi - lo) for a box [lo, hi] in [0, inf) (plain log x when
    lo >= 5 % of hi; a zero lower bound, such as an inflow rate's, is shifted) and
    NaN otherwise. Measured on the uncertain-inflow study's own solves (3-D, ARD,
    principal frame, trained on the first n solves of an active run, errors at the
    later solves in the 99 % posterior region; ``benchmarks/inflow_surrogate.py``):
    RMS error 1.52 -> 0.25 nats (n = 104) and 0.41 -> 0.06 nats (n = 149).
    ``fit_from_config`` fits both scales and keeps the larger evidence
    (``inputs: auto``; the targets are the same, so the evidences compare directly)
    when the kernel has one length scale per input in three or more dimensions; with a
    single length scale, and in one or two dimensions (the 2-D studies), ``auto`` keeps
    linear inputs (:data:`LOG_INPUTS_NOTE`).

Re-deciding the discrete choices (``surrogate.reselect_growth``; :func:`fit_round`)
    :func:`fit_from_config` fits every candidate of the discrete choices (kernel x
    output x input scale x frame: up to 24 GP fits in 3-7D) and keeps the largest
    evidence. In an active design the training set grows by a small batch a round, so
    the winner seldom changes from one round to the next while the search dominates the
    round's time. :func:`fit_round` searches in full in round 0 and once the training
    set has grown by the fraction f since the last search (n >= (1 + f) n_search, a
    geometric schedule: O(log n) searches in a run), and in the other rounds refits only
    the previous choice on all current data (one GP fit; principal frame recomputed,
    warm-started from the previous hyperparameters), with a fall-back to the full search
    when that refit fails or overshoots the bound. The choice and n_search travel with
    the surrogate (``GPSurrogate.selection`` / ``selection_n``, stored in its file). The
    surrogate of the study's result is always a full search.

Constant prior mean (App. D remark; ``mean="constant"``)
    m = min(L) - f_m (max(L) - min(L)),   f_m = ``mean_offset_factor`` = 1.0,
    so far from the data the surrogate log-likelihood falls below every observed
    value (the likelihood tends to zero rather than to exp(0)).

Misfit-shaped prior mean (``mean="quadratic"``; ``surrogate.mean``)
    With the constant mean the surrogate reverts to a floor away from the solves, so
    the SMC posterior sits where the best solves are and an active design crawls up a
    likelihood's slope a few posterior sd per round (measured on the 7-D benchmark,
    docs/bench_active.md). A Gaussian log-likelihood of a smooth forward model is close
    to quadratic near its mode (L = B - Phi, Phi ~ phi0 + 1/2 (x - x0)^T H (x - x0) by
    Gauss-Newton), so the mean is given that shape:

        Phi_m(u) = phi0 + 1/2 | R (u - c) |^2,   R upper triangular, R^T R = H in u,

    in the GP's input frame u (log inputs, box scaling and principal frame included),
    carried through the output transform: m(u) = log(1 + Phi_m(u)) for the log-misfit
    GP (the quadratic misfit, warped as the targets are), m(u) = top - Phi_m(u) for a GP
    of L, top = B (so the mean never exceeds the bound) or max(L) + range(L) without
    one. This is VBMC's negative-quadratic mean function (Acerbi 2018, 2020:
    m(x) = m0 - 1/2 sum_i ((x_i - x0_i) / w_i)^2, fitted with the kernel) with two
    changes: a full Cholesky factor instead of per-axis widths, because the posteriors
    here have ridges (E_i along the inflow rate) that a diagonal quadratic in a
    misplaced frame cannot follow (measured on ``sloppy4d``: the diagonal version
    mispredicted the next batch by 10^2-10^3 nats, the full one by < 0.05), and the
    mean built on the misfit, so that it lives in the log-misfit warping the pipeline
    uses. c, R and phi0 are hyperparameters maximized with the kernel's by the
    evidence (GPy, analytic gradients through a custom mapping), each start from a
    bounded least-squares fit of the mean to the targets. Bounds: c within the box's
    image in the frame widened by half its extent on each side; the diagonal widths
    1 / R_jj between 1e-4 and 1e2 extents; phi0 >= 0. Far from the solves the
    surrogate then keeps climbing toward the fitted mode (and falls off quadratically
    beyond it) instead of reverting to a floor.

Nugget (``surrogate.nugget``)
    ``fixed`` (the paper's): sigma_n^2 = f_n (max(y) - min(y)), f_n = ``nugget_factor``
    = 1e-5, fixed (not optimized), for numerical stability. The range of the targets is
    set by the far points of a design (ridge2d: 890 nats among 64 values, so a noise
    of 0.09 nats sd on every value), so a fixed relative nugget caps the accuracy near
    the mode (docs/bench_active.md, issue 17).

    ``fit``: sigma_n^2 is a hyperparameter of the evidence, maximized with the kernel's
    (the GP noise variance of GP regression, Rasmussen & Williams 2006 Sec. 5.4; VBMC
    fits its GP noise the same way, Acerbi 2018), within

        floor <= sigma_n^2 <= max(var(y), 1e3 floor),

    so that noise-free values are interpolated (the evidence drives the noise to the
    floor) while a solver's discretization noise (FSI) is smoothed over instead of
    interpolated. The floor is absolute, ``nugget_floor`` = s_f^2 in nats^2 of the
    log-likelihood (default 1e-5: VBMC's minimum GP noise, ``tol_gp_noise`` =
    sqrt(1e-5) nats sd), not relative to the range of L, so far points do not raise it.
    For the log-misfit GP it is carried to the units of g by the warping's slope at the
    best training value, dg/dL = -1 / (1 + Phi_min): floor_g = s_f^2 exp(-2 min g).
    The optimizer starts: the first at 10 floor, the others log-uniform between the
    floor and 1e-2 var(y); a refit of :func:`fit_round` adds one start at the previous
    round's kernel hyperparameters and nugget. Should
    K + sigma_n^2 I not factorize in float64 at the optimum (a smooth kernel, dense
    points), sigma_n^2 is raised tenfold until it does (logged; the evidence is
    recomputed there). The fitted value travels in the surrogate file (``nugget``;
    ``nugget_mode`` says which rule made it; files written before it was recorded
    read as ``fixed``).

Training (eq. gploglikeli)
    The kernel variance s^2 and length scale(s) l (and sigma_n^2 with the fitted nugget)
    maximize the evidence log p(L | s^2, l) with GPy's L-BFGS-B (``optimizer="lbfgsb"``) or scaled
    conjugate gradients (``"scg"``), from ``restarts`` starting points: the
    first a fixed default (s^2 = mean((L - m)^2), l = 0.3), the others drawn
    log-uniformly around it from ``numpy.random.default_rng(seed)``. The best
    evidence wins. Failed forward runs (non-finite L) are excluded before
    training; their number is kept in ``n_excluded``, and the points of those with
    L = -inf in ``X_failed``: the sampler's log-likelihood (:meth:`GPSurrogate.loglik`)
    is -inf where they mark the model infeasible (:mod:`bayescalib.inference.feasibility`).

Log-misfit warping (``bound``; the default of the pipeline)
    The Gaussian log-likelihood (eq. loglik) is L = B - Phi with the known
    upper bound B = -n/2 log(2 pi sigma_N^2) and the misfit Phi = D^2 / (2
    sigma_N^2) >= 0. With ``bound=B`` the GP models the warped output
    g = log(1 + Phi) = log(1 + B - L) instead of L, and predictions map back
    through L = B - expm1(max(g, 0)). Hence (i) the surrogate never exceeds the
    bound, so neither does the SMC log-evidence; (ii) the many orders of
    magnitude that Phi spans over a prior box (sharply peaked likelihoods) are
    compressed to a few units of g, where a stationary GP fits well; (iii) far
    from the data the GP reverts to its constant mean, which is placed *above*
    the largest g (m = max(g) + f_m (max(g) - min(g))): a low likelihood, never a
    spurious mode between training points. This is the log-discrepancy model of
    GP-accelerated ABC (Wilkinson 2014; Jarvenpaa et al. 2018), applied to the
    Gaussian likelihood's misfit. The latent variance maps to the likelihood
    scale by the delta method, var(L) = exp(2 g) var(g).

Prediction (eq. posterior_gp)
    mean(x*) = m + k*^T (K + sigma_n^2 I)^{-1} (L - m)
    var(x*)  = k(x*, x*) - k*^T (K + sigma_n^2 I)^{-1} k*     (latent, noise-free)

:class:`GPSurrogate` caches the Cholesky factor of K + sigma_n^2 I and the
weights alpha = (K + sigma_n^2 I)^{-1} (L - m) and evaluates the formulas above
as plain batched array algebra in float64 -- this is what the SMC calls
millions of times. It equals GPy's ``predict_noiseless`` to round-off (tested
to 1e-8 relative); ``gpy_model()`` rebuilds the GPy model with the stored
hyperparameters for comparison.

* CPU (``device="cpu"``): NumPy. Squared distances come from one matrix
  product of augmented inputs [a, |a|^2, 1] @ [-2b, 1, |b|^2]^T with
  sqrt(3)/l folded into the input scaling and s^2 into the weights. Rows are
  processed in chunks small enough that each (chunk, n) kernel block stays in
  cache (the algebra is memory-bound) and that the distance product stays
  below OpenBLAS's multithreading threshold (threaded small products were
  measured 100x slower on a loaded machine). ``threads`` > 1 spreads chunks
  over a thread pool (default 1: on a small machine shared with forward
  solves, extra threads measured slower).
* GPU (``device="auto"`` with CUDA, or any torch device; ``"torch:cpu"`` for
  testing): the same algebra in torch, in chunks of at most
  ``chunk_entries`` kernel entries.
"""

from __future__ import annotations

import itertools
import logging
import math
import os
import sys
import threading
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.config import defaults, validate
from bayescalib.io._atomic_write import atomic_path
from bayescalib.io.header import check_header, write_header

__all__ = ["KERNELS", "GPSurrogate", "fit_from_config", "fit_gp", "fit_round", "kernel_matrix",
           "log_input_offsets", "matern32", "surrogate_settings", "warp_inputs"]

log = logging.getLogger(__name__)

_SQRT3 = math.sqrt(3.0)
_GEMM_SINGLE_THREAD_MNK = 2**18


#: stationary kernels k(r) = s^2 f(c r) of the surrogate: name -> (c, GPy class name).
#: With t = c r: Matérn 3/2 f = (1 + t) e^-t (the paper's, eq. matern32), Matérn 5/2
#: f = (1 + t + t^2/3) e^-t, squared exponential (rbf) f = e^(-t^2) (c = 1/sqrt 2).
KERNELS: dict[str, tuple[float, str]] = {
    "matern32": (_SQRT3, "Matern32"),
    "matern52": (math.sqrt(5.0), "Matern52"),
    "rbf": (math.sqrt(0.5), "RBF"),
}


def _unit_kernel_from_t2(T2: np.ndarray, kernel: str,
                         work: np.ndarray | None = None) -> np.ndarray:
    """f(t) of :data:`KERNELS` from t^2 (any shape), overwriting ``T2``.

    ``work`` (the shape of ``T2``, optional) holds e^-t, so that no temporary array is
    allocated; the values are bitwise those without it."""
    np.maximum(T2, 0.0, out=T2)
    if kernel == "rbf":
        np.negative(T2, out=T2)
        return np.exp(T2, out=T2)
    t2 = T2.copy() if kernel == "matern52" else None
    np.sqrt(T2, out=T2)
    E = np.negative(T2, out=work)
    np.exp(E, out=E)
    T2 += 1.0
    if t2 is not None:
        T2 += t2 / 3.0
    T2 *= E
    return T2


def kernel_matrix(A: np.ndarray, B: np.ndarray, variance: float, lengthscale: np.ndarray,
                  kernel: str = "matern32") -> np.ndarray:
    """Kernel matrix of :data:`KERNELS` between A (m, d) and B (n, d) -> (m, n)."""
    c = KERNELS[kernel][0]
    a = c * np.asarray(A, float) / lengthscale
    b = c * np.asarray(B, float) / lengthscale
    t2 = np.sum(a * a, 1)[:, None] + np.sum(b * b, 1)[None, :] - 2.0 * a @ b.T
    return variance * _unit_kernel_from_t2(t2, kernel)


def matern32(A: np.ndarray, B: np.ndarray, variance: float, lengthscale: np.ndarray) -> np.ndarray:
    """Matérn 3/2 kernel matrix (eq. matern32) between A (m, d) and B (n, d) -> (m, n)."""
    return kernel_matrix(A, B, variance, lengthscale, "matern32")


@cache
def _pool(n: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=n, thread_name_prefix="gp-predict")


def _torch():
    import torch

    return torch


#: device nodes and driver files of which a Linux machine with a GPU that torch can use
#: has at least one (NVIDIA: /dev/nvidia*, /proc/driver/nvidia; ROCm: /dev/kfd; WSL: /dev/dxg)
_GPU_MARKERS = ("/dev/nvidiactl", "/dev/nvidia0", "/proc/driver/nvidia", "/dev/kfd", "/dev/dxg")


def gpu_possible() -> bool:
    """False only where torch certainly sees no GPU: a Linux machine with none of the
    GPU device nodes or driver files of :data:`_GPU_MARKERS` (checked without importing
    torch, whose import costs 5-7 s: measured on the smoke study's figure and per-round
    jobs). True elsewhere, and where torch is already imported."""
    if "torch" in sys.modules or not sys.platform.startswith("linux"):
        return True
    return any(os.path.exists(p) for p in _GPU_MARKERS)


def _resolve_device(device: str) -> str:
    """"auto" -> "cuda" when torch sees a GPU, else "cpu" (the NumPy path).

    "cpu" selects the NumPy implementation; any other value is a torch device
    ("cuda", "cuda:1"; "torch:cpu" runs the torch implementation on the CPU).
    Where no GPU can exist (:func:`gpu_possible`), "auto" is "cpu" without importing
    torch.
    """
    if device != "auto":
        return device
    if not gpu_possible():
        return "cpu"
    try:
        torch = _torch()
    except ImportError:  # pragma: no cover - torch is a dependency
        return "cpu"
    return "cuda" if torch.cuda.is_available() else "cpu"


#: ``GPSurrogate.selection`` of a fit that searched the discrete choices in full, and of
#: one that refitted the previous round's choice (:func:`fit_round`)
_SEARCH = "search"
_REFIT = "refit"


@dataclass
class GPSurrogate:
    """A trained GP surrogate of the log-likelihood with a fast batched predictor.

    Attributes
    ----------
    X_train : (n, d) training inputs in user units (failed runs removed).
    y_train : (n,) GP targets: the log-likelihoods, or their warped values
        g = log(1 + bound - L) when ``bound`` is set (see :attr:`loglik_train`).
    shift, scale : (d,) input scaling u = (x - shift) / scale.
    mean_const : constant prior mean m.
    nugget : nugget (noise) variance sigma_n^2 in the units of ``y_train``.
    nugget_fitted : True when ``nugget`` was fitted by the evidence (``nugget="fit"`` of
        :func:`fit_gp`), False when fixed by the rule of ``nugget_factor``.
    variance : kernel variance s^2.
    lengthscale : (1,) or (d,) length scale(s) on scaled inputs.
    ard : one length scale per input.
    n_excluded : number of training points left out (non-finite L).
    log_marginal_likelihood : evidence at the optimum (eq. gploglikeli, with nugget).
    optimizer, restarts : training settings (metadata).
    chol : (n, n) lower Cholesky factor of K + sigma_n^2 I.
    alpha : (n,) (K + sigma_n^2 I)^{-1} (y - m).
    bound : upper bound B of the log-likelihood (None: unknown). Predictions never
        exceed it.
    warp : the GP models the log-misfit g = log(1 + B - L) (``y_train`` holds g);
        otherwise it models L and predictions are capped at ``bound``.
    kernel : one of :data:`KERNELS` (default the paper's Matérn 3/2).
    rotation : (d, d) orthogonal matrix or None: the GP's inputs are
        u = ((x - shift) / scale) @ rotation (the principal-axes frame of
        :func:`principal_frame`); None: u = (x - shift) / scale.
    log_offset : (d,) or None: input k enters as log(x_k + log_offset_k) before the
        scaling (``shift`` and ``scale`` are then in those units); NaN entries (or
        None) keep x_k linear (:meth:`warp_inputs`).
    mean_function : ``"constant"`` (the prior mean is ``mean_const``) or
        ``"quadratic"`` (the misfit-shaped mean of :func:`quadratic_mean`;
        ``mean_const`` is then NaN and unused).
    mean_center, mean_factor : centre c (d,) and upper-triangular factor R (d, d) of the
        quadratic mean's Hessian R^T R, in the GP's input frame (:meth:`scale_inputs`);
        None for a constant mean.
    mean_misfit_min : misfit phi0 (nats) of the quadratic mean at its centre.
    mean_top : the value the quadratic mean of a GP of L falls from (the bound B, or
        max(L) + range(L) without one); NaN for the log-misfit GP.
    selection : how the discrete choices (kernel, output, input scale, frame) were made:
        ``"search"`` (every candidate fitted, the largest evidence kept:
        :func:`fit_from_config`, or one given choice: :func:`fit_gp`) or ``"refit"`` (the
        previous round's choice refitted, :func:`fit_round`).
    selection_n : number of training values at the last full search of those choices
        (-1: unknown, e.g. a file written before it was recorded).
    X_failed : (F, d) design points whose solve failed (finite inputs, L = -inf; NaN
        marks a failure that says nothing of the model, left out), in user units, or None: with them :meth:`loglik` is -inf where they mark the model
        infeasible (:mod:`bayescalib.inference.feasibility`).
    """

    X_train: np.ndarray
    y_train: np.ndarray
    shift: np.ndarray
    scale: np.ndarray
    mean_const: float
    nugget: float
    variance: float
    lengthscale: np.ndarray
    ard: bool
    n_excluded: int = 0
    log_marginal_likelihood: float = float("nan")
    optimizer: str = "lbfgsb"
    restarts: int = 0
    chol: np.ndarray | None = None
    alpha: np.ndarray | None = None
    device: str = "auto"
    chunk_entries: int = 4_000_000
    cpu_chunk_entries: int = 65536
    threads: int = 1
    bound: float | None = None
    warp: bool = False
    kernel: str = "matern32"
    rotation: np.ndarray | None = None
    log_offset: np.ndarray | None = None
    mean_function: str = "constant"
    mean_center: np.ndarray | None = None
    mean_factor: np.ndarray | None = None
    mean_misfit_min: float = float("nan")
    mean_top: float = float("nan")
    selection: str = _SEARCH
    selection_n: int = -1
    nugget_fitted: bool = False
    X_failed: np.ndarray | None = None
    _cache: dict[str, Any] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self.X_train = np.asarray(self.X_train, float)
        self.y_train = np.asarray(self.y_train, float).reshape(-1)
        self.shift = np.asarray(self.shift, float)
        self.scale = np.asarray(self.scale, float)
        self.lengthscale = np.atleast_1d(np.asarray(self.lengthscale, float))
        if self.rotation is not None:
            self.rotation = np.asarray(self.rotation, float).reshape(self.dim, self.dim)
        if self.log_offset is not None:
            self.log_offset = np.asarray(self.log_offset, float).reshape(self.dim)
            if not np.isfinite(self.log_offset).any():
                self.log_offset = None
        if self.mean_function not in ("constant", "quadratic"):
            raise ValueError(f"mean_function must be 'constant' or 'quadratic', got "
                             f"{self.mean_function!r}")
        if self.mean_function == "quadratic":
            self.mean_center = np.asarray(self.mean_center, float).reshape(self.dim)
            self.mean_factor = np.asarray(self.mean_factor, float).reshape(self.dim, self.dim)
            self.mean_misfit_min = float(self.mean_misfit_min)
            self.mean_top = float(self.mean_top)
        else:
            self.mean_center = self.mean_factor = None
        if self.X_failed is not None:
            self.X_failed = np.asarray(self.X_failed, float).reshape(-1, self.dim)
            if self.X_failed.shape[0] == 0:
                self.X_failed = None
        if self.chol is None or self.alpha is None:
            self._factorize()
        self.device = _resolve_device(self.device)

    # ------------------------------------------------------------------
    @property
    def _torch_device(self) -> str:
        return self.device.removeprefix("torch:")

    @property
    def n_train(self) -> int:
        return int(self.X_train.shape[0])

    @property
    def dim(self) -> int:
        return int(self.X_train.shape[1])

    @property
    def warped(self) -> bool:
        """True when the GP models the log-misfit g = log(1 + bound - L)."""
        return bool(self.warp) and self.bound is not None

    @property
    def loglik_train(self) -> np.ndarray:
        """Training log-likelihoods L (n,), whatever the GP's output transform."""
        return self.loglik_from_latent(self.y_train)

    def loglik_from_latent(self, g: np.ndarray) -> np.ndarray:
        """Map latent GP values to log-likelihoods: L = B - expm1(max(g, 0)) if warped."""
        g = np.asarray(g, float)
        if self.warped:
            return self.bound - np.expm1(np.maximum(g, 0.0))
        if self.bound is not None:
            return np.minimum(g, self.bound)
        return g

    def latent_from_loglik(self, L: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`loglik_from_latent` (values above the bound map to g = 0)."""
        L = np.asarray(L, float)
        if not self.warped:
            return L
        return np.log1p(np.maximum(self.bound - L, 0.0))

    @property
    def hyperparameters(self) -> dict[str, Any]:
        """Kernel variance, length scale(s), mean, nugget (JSON-serializable)."""
        return {
            "kernel": KERNELS[self.kernel][1],
            "variance": float(self.variance),
            "lengthscale": [float(v) for v in self.lengthscale],
            "ard": bool(self.ard),
            "mean": float(self.mean_const) if self.mean_function == "constant" else None,
            "mean_function": self.mean_function,
            "mean_center": None if self.mean_center is None else
            [float(v) for v in self.mean_center],
            "mean_factor": None if self.mean_factor is None else self.mean_factor.tolist(),
            "mean_misfit_min": None if self.mean_function == "constant" else
            float(self.mean_misfit_min),
            "nugget": float(self.nugget),
            "nugget_mode": "fit" if self.nugget_fitted else "fixed",
            "log_marginal_likelihood": float(self.log_marginal_likelihood),
            "input_shift": [float(v) for v in self.shift],
            "input_scale": [float(v) for v in self.scale],
            "output": "log_misfit" if self.warped else "loglik",
            "bound": None if self.bound is None else float(self.bound),
            "input_rotation": None if self.rotation is None else self.rotation.tolist(),
            "input_log_offset": None if self.log_offset is None else
            [None if not math.isfinite(v) else float(v) for v in self.log_offset],
        }

    def warp_inputs(self, X: np.ndarray) -> np.ndarray:
        """User units -> the units of ``shift`` and ``scale``: log(x_k + c_k) for the
        log inputs (``log_offset``), x_k for the others; shape kept (..., d)."""
        return warp_inputs(X, self.log_offset)

    def scale_inputs(self, X: np.ndarray) -> np.ndarray:
        """User units -> GP inputs u = (x' - shift) / scale, times ``rotation`` if set
        (x' = :meth:`warp_inputs` of x)."""
        U = (self.warp_inputs(X) - self.shift) / self.scale
        return U if self.rotation is None else U @ self.rotation

    def _input_map(self) -> np.ndarray:
        """(d, d) matrix M with u / l = (x - shift) @ M (u the GP inputs, l the length scales)."""
        R = np.eye(self.dim) if self.rotation is None else self.rotation
        return R / self.scale[:, None] / self.lengthscale[None, :]

    def prior_mean_latent(self, U: np.ndarray) -> np.ndarray | float:
        """The GP's prior mean at GP inputs U (M, d) (:meth:`scale_inputs`), in the units
        of ``y_train``: (M,) for the quadratic mean, the scalar ``mean_const`` otherwise."""
        if self.mean_function == "constant":
            return self.mean_const
        return quadratic_mean(U, self.mean_center, self.mean_factor, self.mean_misfit_min,
                              self.mean_top, self.warped)

    def prior_mean(self, X: np.ndarray) -> np.ndarray:
        """The GP's prior mean at X (M, d) in user units, in the units of ``y_train``, (M,)."""
        X = np.atleast_2d(np.asarray(X, float))
        return np.broadcast_to(self.prior_mean_latent(self.scale_inputs(X)),
                               (X.shape[0],)).copy()

    def _factorize(self) -> None:
        U = self.scale_inputs(self.X_train)
        K = kernel_matrix(U, U, self.variance, self.lengthscale, self.kernel)
        K[np.diag_indices_from(K)] += self.nugget
        self.chol = np.linalg.cholesky(K)
        from scipy.linalg import cho_solve

        self.alpha = cho_solve((self.chol, True), self.y_train - self.prior_mean_latent(U))

    # ------------------------------------------------------------------
    def _numpy_cache(self) -> dict[str, Any]:
        if "np_Baug" not in self._cache:
            # B = c * u_train / l; kernel rows come from one matrix product
            # [a, |a|^2, 1] @ [-2 B, 1, |b|^2]^T = |a - b|^2 (a = c u / l, c of KERNELS).
            ck = KERNELS[self.kernel][0]
            B = ck * self.scale_inputs(self.X_train) / self.lengthscale
            n = B.shape[0]
            self._cache["np_Baug"] = np.ascontiguousarray(
                np.column_stack([-2.0 * B, np.ones(n), np.sum(B * B, 1)]).T
            )
            self._cache["np_in_scale"] = ck / (self.scale * self.lengthscale)
            if self.rotation is not None:
                self._cache["np_in_map"] = ck * self._input_map()
            self._cache["np_alpha_s2"] = self.variance * self.alpha
        return self._cache

    def _torch_cache(self) -> dict[str, Any]:
        if "t_B" not in self._cache:
            torch = _torch()
            dev = self._torch_device
            B = torch.as_tensor(
                self.scale_inputs(self.X_train) / self.lengthscale, dtype=torch.float64, device=dev
            )
            self._cache["t_B"] = B
            self._cache["t_Bsq"] = (B * B).sum(1)
            self._cache["t_alpha"] = torch.as_tensor(self.alpha, dtype=torch.float64, device=dev)
            self._cache["t_shift"] = torch.as_tensor(self.shift, dtype=torch.float64, device=dev)
            self._cache["t_inv_sl"] = torch.as_tensor(
                1.0 / (self.scale * self.lengthscale), dtype=torch.float64, device=dev
            )
            self._cache["t_map"] = None if self.rotation is None else torch.as_tensor(
                self._input_map(), dtype=torch.float64, device=dev)
            self._cache["t_L"] = torch.as_tensor(self.chol, dtype=torch.float64, device=dev)
        return self._cache

    def _row_buffers(self, rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """This thread's work arrays for a chunk of ``rows`` points: the augmented inputs
        (rows, d + 2) (last column 1), the kernel block and e^-t (rows, n)."""
        local = self._cache.setdefault("np_local", threading.local())
        buf = getattr(local, "buf", None)
        if buf is None or buf[0].shape[0] < rows:
            aug = np.empty((rows, self.dim + 2))
            aug[:, -1] = 1.0
            buf = local.buf = (aug, np.empty((rows, self.n_train)),
                               np.empty((rows, self.n_train)))
        return buf[0][:rows], buf[1][:rows], buf[2][:rows]

    def _unit_kernel_rows(self, Xc: np.ndarray) -> np.ndarray:
        """k(x*, X_train) / s^2 for a chunk of points (c, d) -> (c, n).

        Computed in this thread's preallocated arrays (:meth:`_row_buffers`; one
        memory pass fewer per operation than fresh temporaries, about twice as fast in
        the SMC, bitwise the same values): the result is valid until the thread's next
        call."""
        c = self._numpy_cache()
        Xc = self.warp_inputs(Xc)
        if self.rotation is None:
            A = (Xc - self.shift) * c["np_in_scale"]
        else:
            A = (Xc - self.shift) @ c["np_in_map"]
        Aaug, K, E = self._row_buffers(A.shape[0])
        Aaug[:, : self.dim] = A
        np.sum(A * A, 1, out=Aaug[:, self.dim])
        np.matmul(Aaug, c["np_Baug"], out=K)  # t^2 = (c r)^2
        return _unit_kernel_from_t2(K, self.kernel, E)

    def _predict_numpy(self, X: np.ndarray, return_var: bool):
        from scipy.linalg import solve_triangular

        M = X.shape[0]
        mean = np.empty(M)
        var = np.empty(M) if return_var else None
        alpha_s2 = self._numpy_cache()["np_alpha_s2"]
        # small chunks keep the (chunk, n) kernel block in cache (the algebra is
        # memory-bound); chunks run on a thread pool (NumPy releases the GIL).
        # (the variance's triangular solve is BLAS-3 and prefers larger chunks)
        n = max(self.n_train, 1)
        entries = 16 * self.cpu_chunk_entries if return_var else self.cpu_chunk_entries
        # Keep the distance product (chunk x (d+2)) @ ((d+2) x n) below OpenBLAS's
        # multithreading threshold (~2^19 multiply-adds): on a loaded machine a threaded
        # small GEMM was measured 100-300x slower than a single-threaded one.
        gemm_rows = _GEMM_SINGLE_THREAD_MNK // (n * (self.dim + 2))
        chunk = max(1, min(M, entries // n, max(gemm_rows, 1)))

        def job(s: int) -> None:
            K = self._unit_kernel_rows(X[s : s + chunk])
            mean[s : s + chunk] = K @ alpha_s2 + (
                self.mean_const if self.mean_function == "constant"
                else self.prior_mean(X[s : s + chunk]))
            if return_var:
                V = solve_triangular(self.chol, K.T, lower=True, check_finite=False)
                V *= self.variance
                var[s : s + chunk] = np.maximum(self.variance - np.sum(V * V, 0), 0.0)

        starts = range(0, M, chunk)
        if self.threads > 1 and M > chunk:
            list(_pool(self.threads).map(job, starts))
        else:
            for s in starts:
                job(s)
        return mean, var

    def _predict_torch(self, X: np.ndarray, return_var: bool):
        torch = _torch()
        c = self._torch_cache()
        M = X.shape[0]
        mean = np.empty(M)
        var = np.empty(M) if return_var else None
        chunk = max(1, self.chunk_entries // max(self.n_train, 1))
        with torch.no_grad():
            Xt = torch.as_tensor(self.warp_inputs(X), dtype=torch.float64,
                                 device=self._torch_device)
            for s in range(0, M, chunk):
                if c["t_map"] is None:
                    A = (Xt[s : s + chunk] - c["t_shift"]) * c["t_inv_sl"]
                else:
                    A = (Xt[s : s + chunk] - c["t_shift"]) @ c["t_map"]
                r2 = (A * A).sum(1)[:, None] + c["t_Bsq"][None, :] - 2.0 * (A @ c["t_B"].T)
                t2 = torch.clamp_min_(r2, 0.0).mul_(KERNELS[self.kernel][0] ** 2)
                if self.kernel == "rbf":
                    K = torch.exp(t2.neg_()).mul_(self.variance)
                else:
                    t = torch.sqrt(t2)
                    poly = 1.0 + t + (t2 / 3.0 if self.kernel == "matern52" else 0.0)
                    K = poly.mul_(torch.exp(t.neg())).mul_(self.variance)
                mean[s : s + chunk] = (K @ c["t_alpha"]).cpu().numpy() + (
                    self.mean_const if self.mean_function == "constant"
                    else self.prior_mean(X[s : s + chunk]))
                if return_var:
                    V = torch.linalg.solve_triangular(c["t_L"], K.T, upper=False)
                    v = torch.clamp_min(self.variance - (V * V).sum(0), 0.0)
                    var[s : s + chunk] = v.cpu().numpy()
        return mean, var

    def predict(
        self, X: np.ndarray, return_var: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Posterior mean (and variance) of the log-likelihood (eq. posterior_gp).

        With the log-misfit warping the mean is B - expm1(max(mean_g, 0)) (never
        above the bound B) and the variance exp(2 mean_g) var_g (delta method).

        Parameters
        ----------
        X
            (M, d) points in user units (a single point (d,) is accepted).
        return_var
            Also return the latent (noise-free) posterior variance.

        Returns
        -------
        mean : (M,) in units of log-likelihood
        var : (M,), only if ``return_var``
        """
        if not self.warped:
            if not return_var:
                return self.loglik_from_latent(self.predict_latent(X))
            g, var_g = self.predict_latent(X, True)
            return self.loglik_from_latent(g), var_g
        if not return_var:
            return self.loglik_from_latent(self.predict_latent(X))
        g, var_g = self.predict_latent(X, True)
        return self.loglik_from_latent(g), np.exp(2.0 * np.maximum(g, 0.0)) * var_g

    @property
    def n_failed(self) -> int:
        """Number of failed design points the surrogate knows of (:attr:`X_failed`)."""
        return 0 if self.X_failed is None else int(self.X_failed.shape[0])

    def infeasible(self, X: np.ndarray) -> np.ndarray:
        """Where the failed solves mark the model infeasible, (M,) bool for X (M, d) in
        user units (:class:`~bayescalib.inference.feasibility.FailedRegion` in the GP's
        unit-box inputs); all False without failed points."""
        X = np.atleast_2d(np.asarray(X, float))
        if self.X_failed is None:
            return np.zeros(X.shape[0], bool)
        region = self._cache.get("failed_region")
        if region is None:
            from bayescalib.inference.feasibility import FailedRegion

            region = self._cache["failed_region"] = FailedRegion(
                self.scale_inputs(self.X_train), self.scale_inputs(self.X_failed))
        return region.contains(self.scale_inputs(X))

    def loglik(self, X: np.ndarray) -> np.ndarray:
        """The log-likelihood the sampler targets, (M,): the posterior mean of
        :meth:`predict`, and -inf where the failed solves mark the model infeasible
        (:meth:`infeasible`; the likelihood is taken as zero where the model cannot be
        solved, :mod:`bayescalib.inference.feasibility`). Without failed points it is
        :meth:`predict`'s mean, bitwise."""
        mean = self.predict(X)
        if self.X_failed is not None:
            mean = np.where(self.infeasible(X), -np.inf, mean)
        return mean

    def predict_latent(
        self, X: np.ndarray, return_var: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Posterior mean (and latent variance) of the GP itself, in the units of
        ``y_train`` (the warped output g when ``bound`` is set), shapes (M,)."""
        X = np.asarray(X, float)
        if X.ndim == 1:
            X = X[None, :]
        if X.ndim != 2 or X.shape[1] != self.dim:
            raise ValueError(f"expected inputs of shape (M, {self.dim}), got {X.shape}")
        if self.device == "cpu":
            mean, var = self._predict_numpy(X, return_var)
        else:
            mean, var = self._predict_torch(X, return_var)
        if return_var:
            return mean, var
        return mean

    def latent_cov_factor(self, X: np.ndarray) -> np.ndarray:
        """V = L^{-1} k(X_train, X), shape (n, M), for posterior covariances of the
        latent GP: cov(a, b) = k(a, b) - V_a^T V_b (batch acquisition)."""
        from scipy.linalg import solve_triangular

        K = self.latent_kernel(self.X_train, X)
        return solve_triangular(self.chol, K, lower=True, check_finite=False)

    def latent_kernel(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """Prior kernel matrix k(A, B) of the latent GP (inputs in user units), (m, n)."""
        return kernel_matrix(self.scale_inputs(A), self.scale_inputs(B), self.variance,
                             self.lengthscale, self.kernel)

    __call__ = predict

    # ------------------------------------------------------------------
    def gpy_model(self):
        """A GPy ``GPRegression`` with the stored hyperparameters (inputs: scaled).

        Use ``model.predict_noiseless(surrogate.scale_inputs(X))`` to compare.
        """
        mapping = None
        if self.mean_function == "quadratic":
            lo, hi = frame_extent(self.rotation, self.dim)
            ext = hi - lo
            mapping = _quadratic_mapping_class()(
                self.dim, lo - QUAD_CENTER_MARGIN * ext, hi + QUAD_CENTER_MARGIN * ext, ext,
                self.mean_top, self.warped, self.mean_center, self.mean_factor,
                self.mean_misfit_min, fixed=True)
        return _build_gpy(
            self.scale_inputs(self.X_train),
            self.y_train,
            self.mean_const,
            self.variance,
            self.lengthscale,
            self.nugget,
            self.ard,
            self.kernel,
            mapping,
        )

    def gpy_predict(self, X: np.ndarray, return_var: bool = False, model=None):
        """Prediction through GPy itself (slow reference; for tests and benchmarks)."""
        model = self.gpy_model() if model is None else model
        mu, var = model.predict_noiseless(self.scale_inputs(np.atleast_2d(X)))
        mu, var = mu[:, 0], var[:, 0]
        if self.warped:
            mu, var = self.loglik_from_latent(mu), np.exp(2.0 * np.maximum(mu, 0.0)) * var
        return (mu, var) if return_var else mu

    # ------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the surrogate to HDF5 (atomically): data, scaling, hyperparameters, factors."""
        import h5py

        with atomic_path(path, suffix=".h5") as tmp, h5py.File(tmp, "w") as f:
            write_header(f, "surrogate")
            self.write_group(f)

    def write_group(self, f) -> None:
        """Write the surrogate's data into the open h5py file or group ``f`` (the layout
        of :meth:`save`, without the file header: an emulator stores one per output
        coordinate, :mod:`bayescalib.inference.emulator`)."""
        f.attrs["kernel"] = KERNELS[self.kernel][1]
        f.create_dataset("X_train", data=self.X_train)
        f.create_dataset("y_train", data=self.y_train)
        f.create_dataset("input_shift", data=self.shift)
        f.create_dataset("input_scale", data=self.scale)
        f.create_dataset("lengthscale", data=self.lengthscale)
        f.create_dataset("chol", data=self.chol, compression="gzip")
        f.create_dataset("alpha", data=self.alpha)
        for k in ("mean_const", "nugget", "variance", "log_marginal_likelihood"):
            f.attrs[k] = float(getattr(self, k))
        f.attrs["ard"] = bool(self.ard)
        f.attrs["n_excluded"] = int(self.n_excluded)
        f.attrs["optimizer"] = self.optimizer
        f.attrs["restarts"] = int(self.restarts)
        f.attrs["bound"] = float("nan") if self.bound is None else float(self.bound)
        f.attrs["warp"] = bool(self.warp)
        if self.rotation is not None:
            f.create_dataset("input_rotation", data=self.rotation)
        if self.log_offset is not None:
            f.create_dataset("input_log_offset", data=self.log_offset)
        f.attrs["mean_function"] = self.mean_function
        if self.mean_function == "quadratic":
            f.create_dataset("mean_center", data=self.mean_center)
            f.create_dataset("mean_factor", data=self.mean_factor)
            f.attrs["mean_misfit_min"] = float(self.mean_misfit_min)
            f.attrs["mean_top"] = float(self.mean_top)
        # added within format version 3 (readers ignore unknown attributes)
        f.attrs["selection"] = self.selection
        f.attrs["selection_n"] = int(self.selection_n)
        f.attrs["nugget_mode"] = "fit" if self.nugget_fitted else "fixed"
        if self.X_failed is not None:
            f.create_dataset("X_failed", data=self.X_failed)

    @classmethod
    def load(cls, path: str | Path, device: str = "auto") -> GPSurrogate:
        """Read a surrogate written by :meth:`save`; predictions are reproduced exactly."""
        import h5py

        with h5py.File(path, "r") as f:
            check_header(f, "surrogate", path)
            return cls.read_group(f, device=device)

    @classmethod
    def read_group(cls, f, device: str = "auto") -> GPSurrogate:
        """Read a surrogate from the open h5py file or group ``f`` (:meth:`write_group`)."""
        return cls(
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
            # files written before the fitted nugget: the fixed rule
            nugget_fitted=_plain_str(f.attrs.get("nugget_mode", "fixed")) == "fit",
            # files written before the failed points were kept: none known
            X_failed=f["X_failed"][()] if "X_failed" in f else None,
        )

    def loo_residuals(self) -> np.ndarray:
        """Leave-one-out residuals y_i - mean_{-i}(x_i) = alpha_i / [(K + s_n^2 I)^{-1}]_ii, (n,).

        Closed form (Rasmussen & Williams 2006, eq. 5.12) at fixed hyperparameters.
        """
        from scipy.linalg import cho_solve

        Kinv = cho_solve((self.chol, True), np.eye(self.n_train))
        return self.alpha / np.diag(Kinv)


#: shift of a log input whose box starts near zero, as a share of its upper bound
LOG_OFFSET_SHARE = 0.05
#: why ``inputs: auto`` keeps linear inputs for a kernel with a single length scale and in
#: one or two dimensions (the 2-D studies), measured with the default study (2-D, default
#: mesh, seed 1, one length scale):
#: with log inputs the evidence chose them in every round, the posterior stayed the
#: same (E 380.3 +- 62 Pa, nu 0.195 +- 0.21 against 381.4 +- 61, 0.200 +- 0.21) but
#: the run needed 97 solves instead of 43 (the exploring picks went to the stretched
#: low-E end of the box, the band's tail, and missed there by 1.5-2.3 nats). With one
#: length scale per input and the fitted nugget (the defaults since issue 17) the smoke
#: study (coarse mesh, design seeds 1-3, benchmarks/bench_active_fsi.py) gave the same with
#: both scales: Hellinger <= 0.1 from 18/23/28 solves (log tried) and 18/18/28 (linear),
#: so the 2-D studies keep linear inputs.
LOG_INPUTS_NOTE = ("log inputs are tried with per-input length scales from three "
                   "dimensions on only")


def log_input_offsets(bounds: np.ndarray) -> np.ndarray | None:
    """Offsets c (d,) of the log inputs for a design box (d, 2): input k enters the GP
    as log(x_k + c_k) when its box lies in [0, inf), with c_k = max(0, 0.05 hi - lo)
    (a box starting at zero, such as an inflow rate's, is shifted by 5 % of its upper
    bound; one starting at >= 5 % of it is logged as it is); NaN for the other inputs.
    None when no input qualifies."""
    b = np.asarray(bounds, float)
    lo, hi = b[:, 0], b[:, 1]
    ok = (lo >= 0.0) & (hi > lo) & np.isfinite(hi)
    if not ok.any():
        return None
    return np.where(ok, np.maximum(0.0, LOG_OFFSET_SHARE * hi - lo), np.nan)


def warp_inputs(X: np.ndarray, log_offset: np.ndarray | None) -> np.ndarray:
    """log(x_k + c_k) for the inputs with a finite offset c_k, x_k for the others
    (X (..., d) in user units; a value at or below -c_k maps to log of the smallest
    positive float instead of -inf)."""
    X = np.asarray(X, float)
    if log_offset is None:
        return X
    m = np.isfinite(log_offset)
    out = X.copy()
    out[..., m] = np.log(np.maximum(X[..., m] + log_offset[m], np.finfo(float).tiny))
    return out


# ---------------------------------------------------------------------------------------
# misfit-shaped (negative-quadratic) prior mean

#: smallest and largest width 1 / R_jj of the quadratic mean along input j, as shares of
#: the input frame's extent (a width of the whole extent changes the misfit by 1/2 nat
#: across the box: a direction the likelihood hardly sees)
QUAD_WIDTH_SHARE = (1e-4, 1e2)
#: how far outside the box (in the GP's input frame) the quadratic's centre may lie, as a
#: share of the box's extent on each side
QUAD_CENTER_MARGIN = 0.5


def frame_extent(rotation: np.ndarray | None, d: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper ends (d,) of the unit box [0, 1]^d in the GP's input frame u V:
    coordinate j of u V ranges over [sum_i min(0, V_ij), sum_i max(0, V_ij)]."""
    if rotation is None:
        return np.zeros(d), np.ones(d)
    V = np.asarray(rotation, float)
    return np.minimum(V, 0.0).sum(0), np.maximum(V, 0.0).sum(0)


def quadratic_misfit(U: np.ndarray, center: np.ndarray, factor: np.ndarray,
                     misfit_min: float) -> np.ndarray:
    """The prior mean's misfit Phi_m(u) = phi0 + 1/2 |R (u - c)|^2, (M,), for U (M, d) in
    the GP's input frame (nats); R (d, d) upper triangular, R^T R the misfit's Hessian."""
    Z = (np.asarray(U, float) - center) @ np.asarray(factor, float).T
    return misfit_min + 0.5 * np.einsum("ij,ij->i", Z, Z)


def quadratic_mean(U: np.ndarray, center: np.ndarray, factor: np.ndarray, misfit_min: float,
                   top: float, warped: bool) -> np.ndarray:
    """Misfit-shaped prior mean at U (M, d), in the GP's output units (M,).

    The misfit Phi_m of :func:`quadratic_misfit` is carried through the GP's output
    transform: log1p(Phi_m) for the log-misfit GP, top - Phi_m for a GP of L itself
    (top = the likelihood's bound B when known, so the mean never exceeds it)."""
    phi = quadratic_misfit(U, center, factor, misfit_min)
    return np.log1p(phi) if warped else top - phi


class _QuadraticParams:
    """The map between the quadratic mean's unconstrained-ish parameter vector
    p = [s (d), rho (d), off (d (d - 1) / 2), phi0] and (c, R, phi0):
    c = c_lo + (c_hi - c_lo) s with s in [0, 1]; R_jj = exp(rho_j) / e_j with
    rho_j in [-log 1e2, -log 1e-4] (:data:`QUAD_WIDTH_SHARE`); R_jk = off_jk / e_k above
    the diagonal (free); phi0 >= 0 (e: the frame's extent)."""

    def __init__(self, c_lo: np.ndarray, c_hi: np.ndarray, extent: np.ndarray):
        self.c_lo, self.c_span = np.asarray(c_lo, float), np.asarray(c_hi - c_lo, float)
        self.extent = np.asarray(extent, float)
        self.d = d = self.extent.size
        self.iu = np.triu_indices(d, 1)
        self.rho_bounds = (-np.log(QUAD_WIDTH_SHARE[1]), -np.log(QUAD_WIDTH_SHARE[0]))

    def unpack(self, s, rho, off, phi0) -> tuple[np.ndarray, np.ndarray, float]:
        R = np.diag(np.exp(np.asarray(rho, float)) / self.extent)
        R[self.iu] = np.asarray(off, float) / self.extent[self.iu[1]]
        return self.c_lo + self.c_span * np.asarray(s, float), R, float(phi0)

    def pack(self, center, factor, phi0) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        R = np.asarray(factor, float)
        s = np.clip((np.asarray(center, float) - self.c_lo) / self.c_span, 1e-9, 1 - 1e-9)
        rho = np.clip(np.log(np.diag(R) * self.extent), self.rho_bounds[0] + 1e-9,
                      self.rho_bounds[1] - 1e-9)
        return s, rho, R[self.iu] * self.extent[self.iu[1]], max(float(phi0), 1e-12)

    def gradients(self, U: np.ndarray, center: np.ndarray, R: np.ndarray, g: np.ndarray):
        """Gradients of sum_i g_i Phi_m(u_i) with respect to (s, rho, off, phi0)."""
        D = U - center
        Z = D @ R.T
        GR = (g[:, None] * Z).T @ D  # d/dR_jk = sum_i g_i z_ij d_ik
        return (-(g @ (Z @ R)) * self.c_span, np.diag(GR) * np.diag(R),
                GR[self.iu] / self.extent[self.iu[1]], float(np.sum(g)))

    def jacobian(self, U: np.ndarray, center: np.ndarray, R: np.ndarray) -> np.ndarray:
        """d Phi_m(u_i) / d (s, rho, off, phi0), shape (n, 2 d + d (d - 1) / 2 + 1)."""
        D = U - center
        Z = D @ R.T
        j, k = self.iu
        return np.column_stack([-(Z @ R) * self.c_span, Z * D * np.diag(R),
                                Z[:, j] * D[:, k] / self.extent[k], np.ones(U.shape[0])])


@cache
def _quadratic_mapping_class():
    """The GPy mapping of the misfit-shaped prior mean (built on first use: GPy is
    imported lazily).

    Parameters (:class:`_QuadraticParams`), in paramz transforms so that L-BFGS-B works
    without constraints: ``s`` (d,) bounded in (0, 1), ``rho`` (d,) bounded, ``off``
    free, ``phi0`` positive. The evidence's gradient reaches them through dL/dm (GPy's
    exact inference passes it to ``update_gradients``)."""
    from GPy.core import Mapping
    from GPy.core.parameterization import Param

    class MisfitQuadratic(Mapping):
        def __init__(self, d: int, c_lo: np.ndarray, c_hi: np.ndarray, extent: np.ndarray,
                     top: float, warped: bool, center: np.ndarray, factor: np.ndarray,
                     misfit_min: float, fixed: bool = False):
            super().__init__(input_dim=d, output_dim=1, name="misfit_quadratic")
            self.par = _QuadraticParams(c_lo, c_hi, extent)
            self.top, self.warped = float(top), bool(warped)
            s, rho, off, phi0 = self.par.pack(center, factor, misfit_min)
            self.s, self.rho = Param("s", s), Param("rho", rho)
            self.off, self.phi0 = Param("off", off), Param("phi0", phi0)
            self.link_parameters(self.s, self.rho, self.off, self.phi0)
            if fixed:  # a stored surrogate: its exact values, no transform round trip
                self.fix()
                self._exact = (np.asarray(center, float), np.asarray(factor, float),
                               float(misfit_min))
            else:
                self._exact = None
                self.s.constrain_bounded(0.0, 1.0, warning=False)
                self.rho.constrain_bounded(*self.par.rho_bounds, warning=False)
                self.phi0.constrain_positive(warning=False)

        def start(self) -> tuple[np.ndarray, ...]:
            return tuple(np.array(p, float) for p in (self.s, self.rho, self.off, self.phi0))

        def set(self, values: tuple[np.ndarray, ...]) -> None:
            self.s[:], self.rho[:], self.off[:], self.phi0[:] = values

        def values(self) -> tuple[np.ndarray, np.ndarray, float]:
            """(centre (d,), factor R (d, d), misfit at the centre)."""
            if self._exact is not None:
                return self._exact
            return self.par.unpack(self.s, self.rho, self.off, self.phi0[0])

        def f(self, X):
            c, R, p = self.values()
            return quadratic_mean(X, c, R, p, self.top, self.warped)[:, None]

        def _dm_dphi(self, X):
            c, R, p = self.values()
            phi = quadratic_misfit(X, c, R, p)
            return c, R, (1.0 / (1.0 + phi) if self.warped else -np.ones_like(phi))

        def update_gradients(self, dL_dF, X):
            c, R, dm = self._dm_dphi(X)
            gs, grho, goff, gphi = self.par.gradients(X, c, R, dL_dF[:, 0] * dm)
            self.s.gradient, self.rho.gradient, self.off.gradient = gs, grho, goff
            self.phi0.gradient = gphi

        def gradients_X(self, dL_dF, X):
            c, R, dm = self._dm_dphi(X)
            return (dL_dF[:, 0] * dm)[:, None] * ((X - c) @ R.T @ R)

    return MisfitQuadratic


def _prefit_quadratic(U: np.ndarray, y: np.ndarray, c_lo: np.ndarray, c_hi: np.ndarray,
                      extent: np.ndarray, top: float, warped: bool
                      ) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares fit of the misfit-shaped mean to the targets: the start of the
    evidence maximization. From the centre at the best training point, widths a third of
    the frame's extent, no correlation and phi0 the smallest training misfit, bounded
    least squares (scipy ``least_squares``, trust-region reflective) over the parameters
    of :class:`_QuadraticParams`.

    Returns (centre (d,), factor R (d, d), phi0)."""
    from scipy.optimize import least_squares

    par = _QuadraticParams(c_lo, c_hi, extent)
    d, k = par.d, len(par.iu[0])
    phi_train = np.expm1(y) if warped else top - y
    best = int(np.argmin(phi_train))
    c0 = np.clip(U[best], c_lo, c_hi)
    s0, rho0, off0, phi00 = par.pack(c0, np.diag(3.0 / par.extent), float(phi_train.min()))
    x0 = np.concatenate([s0, rho0, off0, [phi00]])
    lb = np.concatenate([np.zeros(d), np.full(d, par.rho_bounds[0]), np.full(k, -np.inf), [0.0]])
    ub = np.concatenate([np.ones(d), np.full(d, par.rho_bounds[1]), np.full(k, np.inf),
                         [max(float(phi_train.max()), 1.0)]])
    x0 = np.clip(x0, np.where(np.isfinite(lb), lb + 1e-9, lb),
                 np.where(np.isfinite(ub), ub - 1e-9, ub))

    def unpack(p):
        return par.unpack(p[:d], p[d:2 * d], p[2 * d:2 * d + k], p[-1])

    def resid(p):
        return quadratic_mean(U, *unpack(p), top, warped) - y

    def jac(p):
        c, R, p0 = unpack(p)
        dm = 1.0 / (1.0 + quadratic_misfit(U, c, R, p0)) if warped else -np.ones(U.shape[0])
        return dm[:, None] * par.jacobian(U, c, R)

    try:
        p = least_squares(resid, x0, jac=jac, bounds=(lb, ub), method="trf", max_nfev=200).x
    except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - degenerate targets
        p = x0
    return par.unpack(p[:d], p[d:2 * d], p[2 * d:2 * d + k], p[-1])


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


def _build_gpy(U, y, mean_const, variance, lengthscale, nugget, ard, kernel="matern32",
               mapping=None, noise_bounds=None):
    """GPy ``GPRegression`` on the GP inputs U with the nugget ``nugget``: fixed, or free
    within ``noise_bounds`` = (floor, upper) (the fitted nugget); the prior mean is
    ``mapping`` (a GPy mapping, e.g. the quadratic one) or the fixed constant ``mean_const``."""
    import GPy

    d = U.shape[1]
    kern = getattr(GPy.kern, KERNELS[kernel][1])(
        input_dim=d,
        variance=float(variance),
        lengthscale=np.array(lengthscale, float) if ard else float(np.ravel(lengthscale)[0]),
        ARD=ard,
    )
    if mapping is None:
        mf = GPy.mappings.Constant(d, 1, value=float(mean_const))
        mf.fix()
    else:
        mf = mapping
    model = GPy.models.GPRegression(
        np.asarray(U, float), np.asarray(y, float)[:, None], kernel=kern, mean_function=mf,
        noise_var=float(nugget),
    )
    if noise_bounds is None:
        model.Gaussian_noise.variance.fix()
    else:
        model.Gaussian_noise.variance.constrain_bounded(*map(float, noise_bounds),
                                                         warning=False)
    return model


def fit_gp(
    X: np.ndarray,
    y: np.ndarray,
    *,
    kernel: str,
    nugget: str,
    mean: str,
    ard: bool,
    warp: bool | None = None,
    optimizer: str | None = None,
    restarts: int | None = None,
    seed: int | None = None,
    bounds: np.ndarray | None = None,
    mean_offset_factor: float | None = None,
    nugget_factor: float | None = None,
    nugget_floor: float | None = None,
    max_iters: int = 1000,
    device: str = "auto",
    bound: float | None = None,
    rotation: np.ndarray | None = None,
    log_offset: np.ndarray | None = None,
    warm_start: tuple[float, np.ndarray] | tuple[float, np.ndarray, float] | None = None,
) -> GPSurrogate:
    """Train one GP surrogate of the log-likelihood (paper Sec. 3.2, App. D).

    One model, every choice of it given: the kernel, the nugget, the mean, the length
    scales and (with a ``bound``) the output are required keywords, since the study's
    ``surrogate`` section decides them, some by a search over candidates that one fit
    cannot make (``kernel: auto``, ``ard: auto``, ``output: auto``). The study's surrogate
    is :func:`fit_from_config` (with :func:`surrogate_settings` from Python); this is
    the fit of one of its candidates. The optimizer's settings (``optimizer``,
    ``restarts``, ``seed``, ``mean_offset_factor``, ``nugget_factor``, ``nugget_floor``)
    left out (None) are the schema's defaults of the ``surrogate`` section
    (:func:`bayescalib.config.defaults`), so that they live in one place.

    Parameters
    ----------
    X
        (n, d) design points in user units.
    y
        (n,) log-likelihood values; non-finite entries (failed runs) are excluded.
    kernel
        One of :data:`KERNELS` (the paper's: ``"matern32"``).
    nugget
        ``"fixed"``: sigma_n^2 by the rule of ``nugget_factor`` (the paper's); ``"fit"``:
        sigma_n^2 maximizes the evidence with the kernel's hyperparameters, at least the
        floor (module docstring).
    mean
        ``"constant"``: the fixed constant mean of ``mean_offset_factor``;
        ``"quadratic"``: the misfit-shaped mean (module docstring), its centre, widths
        and phi0 fitted by the evidence jointly with the kernel, starting from a
        least-squares fit to the targets (:func:`_prefit_quadratic`).
    ard
        Per-dimension length scales instead of one.
    warp
        With a ``bound`` (then required): True models the log-misfit
        g = log(1 + B - y) (module docstring; values above B from round-off count as
        g = 0), False L itself. Without a bound: unused.
    optimizer
        ``"lbfgsb"`` or ``"scg"`` (GPy optimizers).
    restarts
        Number of optimizer starts (>= 1), seeded by ``seed``.
    bounds
        (d, 2) design box for the input scaling; default: min/max of ``X``.
    mean_offset_factor, nugget_factor
        m = min(y) - mean_offset_factor * (max(y) - min(y));
        sigma_n^2 = nugget_factor * (max(y) - min(y)) (``nugget="fixed"``). With ``bound``
        the same rules act on the warped values g, with the mean placed above
        them: m = max(g) + mean_offset_factor * (max(g) - min(g)).
    nugget_floor
        Floor s_f^2 of the fitted nugget, in nats^2 of the log-likelihood (carried to the
        units of g for the log-misfit GP), > 0; unused with ``nugget="fixed"``.
    max_iters
        Iteration limit of each optimizer run.
    device
        Torch device of the fast predictor ("auto": CUDA when available).
    bound
        Known upper bound B of the log-likelihood; predictions never exceed it.
        None: unknown (the paper's surrogate, uncapped).
    rotation
        (d, d) orthogonal matrix: the GP's inputs are the box-scaled inputs times it
        (:func:`principal_frame`); None: the box-scaled inputs themselves.
    log_offset
        (d,) offsets of the log inputs (:func:`log_input_offsets`; NaN: linear), applied
        before the box scaling (the bounds are mapped alike); None: all linear.
    warm_start
        (kernel variance, length scale(s) of shape (1,) or (d,)[, nugget]) of the first
        optimizer start (a warm start, e.g. the previous round's optimum,
        :func:`fit_round`; the nugget is used with ``nugget="fit"`` only, clipped to its
        bounds); None: the fixed default. The other starts are drawn as without it. With
        ``nugget="fit"`` the warm start comes on top of the ``restarts`` starts (the fixed
        default included); with a fixed nugget it replaces the fixed default.

    Returns
    -------
    GPSurrogate

    Raises
    ------
    ValueError
        Fewer than two finite training values, bad shapes or options.
    """
    schema_default = defaults("inference", "surrogate")
    optimizer = schema_default["optimizer"] if optimizer is None else optimizer
    restarts = schema_default["restarts"] if restarts is None else restarts
    seed = schema_default["seed"] if seed is None else seed
    mean_offset_factor = schema_default["mean_offset_factor"] if mean_offset_factor is None \
        else mean_offset_factor
    nugget_factor = schema_default["nugget_factor"] if nugget_factor is None else nugget_factor
    nugget_floor = schema_default["nugget_floor"] if nugget_floor is None else nugget_floor
    X = np.asarray(X, float)
    y = np.asarray(y, float).reshape(-1)
    if X.ndim != 2 or X.shape[0] != y.shape[0]:
        raise ValueError(f"X must be (n, d) and y (n,), got {X.shape} and {y.shape}")
    if bound is not None and warp is None:
        raise ValueError("warp must be given with a bound: True models the log-misfit, "
                         "False the log-likelihood itself")
    if optimizer not in ("lbfgsb", "scg"):
        raise ValueError(f"optimizer must be 'lbfgsb' or 'scg', got {optimizer!r}")
    if restarts < 1:
        raise ValueError(f"restarts must be >= 1, got {restarts}")
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {sorted(KERNELS)}, got {kernel!r}")
    if mean not in ("constant", "quadratic"):
        raise ValueError(f"mean must be 'constant' or 'quadratic', got {mean!r}")
    if nugget not in ("fixed", "fit"):
        raise ValueError(f"nugget must be 'fixed' or 'fit', got {nugget!r}")
    if not (math.isfinite(float(nugget_floor)) and nugget_floor > 0):
        raise ValueError(f"nugget_floor must be a positive number, got {nugget_floor!r}")
    ok = np.isfinite(y) & np.all(np.isfinite(X), axis=1)
    n_excluded = int((~ok).sum())
    X_failed = X[np.isneginf(y) & np.all(np.isfinite(X), axis=1)]  # NaN: no value, no region
    X, y = X[ok], y[ok]
    if X.shape[0] < 2:
        raise ValueError(f"need at least 2 finite training values, got {X.shape[0]}")
    d = X.shape[1]
    if log_offset is not None:
        log_offset = np.asarray(log_offset, float).reshape(d)
        if not np.isfinite(log_offset).any():
            log_offset = None
    Xw = warp_inputs(X, log_offset)
    if bounds is not None:
        b = warp_inputs(np.asarray(bounds, float).T, log_offset).T
        shift, scale = b[:, 0].copy(), b[:, 1] - b[:, 0]
    else:
        shift = Xw.min(0)
        scale = Xw.max(0) - shift
    scale = np.where(scale > 0, scale, 1.0)
    U = (Xw - shift) / scale
    if rotation is not None:
        rotation = np.asarray(rotation, float)
        if rotation.shape != (d, d) or not np.allclose(rotation.T @ rotation, np.eye(d),
                                                         atol=1e-8):
            raise ValueError(f"rotation must be an orthogonal ({d}, {d}) matrix")
        U = U @ rotation
    if bound is not None:
        if not math.isfinite(float(bound)):
            raise ValueError(f"bound must be finite, got {bound!r}")
        bound = float(bound)
    warp = bool(warp and bound is not None)
    if warp:
        y = np.log1p(np.maximum(bound - y, 0.0))
    y_range = float(y.max() - y.min())
    if y_range <= 0:
        y_range = max(abs(float(y.max())), 1.0)
    if not warp:  # far from the data: below every observed log-likelihood
        mean_const = float(y.min() - mean_offset_factor * y_range)
    else:  # far from the data: above every observed misfit
        mean_const = float(y.max() + mean_offset_factor * y_range)
    noise_bounds = None
    if nugget == "fit":  # floor in nats^2 of L, carried to g by dg/dL at the best value
        floor = float(nugget_floor) * (math.exp(-2.0 * float(y.min())) if warp else 1.0)
        noise_bounds = (floor, max(float(np.var(y)), NUGGET_UPPER_FLOORS * floor))
        nugget0 = NUGGET_START_FLOORS * floor
    else:
        nugget0 = float(nugget_factor * y_range)

    mapping, quad0, top = None, None, float("nan")
    if mean == "quadratic":
        f_lo, f_hi = frame_extent(rotation, d)
        ext = f_hi - f_lo
        c_lo, c_hi = f_lo - QUAD_CENTER_MARGIN * ext, f_hi + QUAD_CENTER_MARGIN * ext
        if not warp:  # the mean of L falls from the bound (or above every value)
            top = bound if bound is not None else float(y.max() + y_range)
        quad0 = _prefit_quadratic(U, y, c_lo, c_hi, ext, top, warp)
        mapping = _quadratic_mapping_class()(d, c_lo, c_hi, ext, top, warp, *quad0)
        start = mapping.start()
        m_train = quadratic_mean(U, *quad0, top, warp)
        mean_const = float("nan")
    else:
        m_train = mean_const
    v0 = float(np.mean((y - m_train) ** 2))
    v0 = v0 if v0 > 0 else y_range**2
    l0 = np.full(d if ard else 1, 0.3)
    model = _build_gpy(U, y, mean_const, v0, l0, nugget0, ard, kernel, mapping, noise_bounds)
    rng = np.random.default_rng(seed)
    best = None
    # with the fitted nugget a warm start is one start more, before the default one: near
    # the floor the evidence has more local optima, and a previous round's optimum alone
    # was measured 18 nats of evidence below the default start's (test_surrogate_reselect)
    extra = int(warm_start is not None and noise_bounds is not None)
    for k in range(restarts + extra):
        r = k - extra  # -1: the extra warm start
        s2 = nugget0
        if warm_start is not None and (r < 0 or (r == 0 and not extra)):
            v = float(warm_start[0])
            ls = np.broadcast_to(np.asarray(warm_start[1], float), l0.shape)
            if len(warm_start) > 2 and warm_start[2] is not None:
                s2 = float(warm_start[2])
        elif r == 0:
            v, ls = v0, l0
        else:
            v = v0 * 10 ** rng.uniform(-1.0, 1.0)
            ls = 10 ** rng.uniform(np.log10(0.05), np.log10(1.0), size=l0.shape)
            if noise_bounds is not None:  # drawn only when fitted: fixed runs keep their draws
                s2_hi = max(NUGGET_RESTART_SHARE * noise_bounds[1], noise_bounds[0])
                s2 = 10 ** rng.uniform(np.log10(noise_bounds[0]), np.log10(s2_hi))
        model.kern.variance[:] = v
        model.kern.lengthscale[:] = ls
        if noise_bounds is not None:  # strictly inside the bounds of the logistic transform
            lo_n, hi_n = noise_bounds
            model.Gaussian_noise.variance[:] = min(max(s2, lo_n * (1 + 1e-9)), hi_n * (1 - 1e-9))
        if mapping is not None:  # every start from the least-squares mean
            mapping.set(start)
        try:
            with np.errstate(over="ignore"), warnings.catch_warnings():
                # paramz's log-exp transform overflows harmlessly on wild line-search steps
                warnings.filterwarnings("ignore", message="overflow encountered", category=RuntimeWarning)
                model.optimize(optimizer=optimizer, max_iters=max_iters, messages=False)
            lml = float(model.log_likelihood())
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            log.warning("GP restart %d failed: %s", r, exc)
            continue
        log.info("GP restart %d: log evidence %.6g", r, lml)
        if np.isfinite(lml) and (best is None or lml > best[0]):
            best = (lml, float(model.kern.variance[0]), np.array(model.kern.lengthscale, float),
                    None if mapping is None else mapping.values(),
                    float(model.Gaussian_noise.variance[0]))
    if best is None:
        raise RuntimeError("every GP hyperparameter optimization failed")
    lml, var, ls, quad, nugget_var = best
    if noise_bounds is None:
        nugget_var = nugget0
    if noise_bounds is not None:
        m_best = mean_const if quad is None else quadratic_mean(U, *quad, top, warp)
        nugget_var, lml = _factorizable_nugget(U, y - m_best, var, ls, kernel, nugget_var, lml)
    quad = quad if quad is not None else (None, None, float("nan"))
    return GPSurrogate(
        X_train=X,
        y_train=y,
        shift=shift,
        scale=scale,
        mean_const=mean_const,
        nugget=nugget_var,
        variance=var,
        lengthscale=ls,
        ard=ard,
        n_excluded=n_excluded,
        log_marginal_likelihood=lml,
        optimizer=optimizer,
        restarts=restarts,
        device=device,
        bound=bound,
        warp=warp,
        kernel=kernel,
        rotation=rotation,
        log_offset=log_offset,
        mean_function=mean,
        mean_center=quad[0],
        mean_factor=quad[1],
        mean_misfit_min=quad[2],
        mean_top=top,
        nugget_fitted=noise_bounds is not None,
        X_failed=X_failed,
    )


#: fitted nugget (:func:`fit_gp`, ``nugget="fit"``): the first optimizer start at this many
#: floors, the upper bound at least this many floors above it (else var(y)), the other
#: starts log-uniform up to this share of the upper bound
NUGGET_START_FLOORS = 10.0
NUGGET_UPPER_FLOORS = 1e3
NUGGET_RESTART_SHARE = 1e-2
#: the fitted nugget is raised tenfold at most this many times until K + sigma_n^2 I factorizes
NUGGET_RAISES = 8


def _factorizable_nugget(U: np.ndarray, r: np.ndarray, variance: float,
                         lengthscale: np.ndarray, kernel: str, nugget: float, lml: float
                         ) -> tuple[float, float]:
    """The fitted nugget, raised tenfold until K + sigma_n^2 I has a float64 Cholesky factor
    (GPy's own factorization adds jitter silently; the predictor does not), and the
    evidence there: (nugget, log evidence). ``r`` (n,): the targets minus the prior mean;
    U (n, d): the GP inputs. Unchanged (``nugget``, ``lml``) when it factorizes as it is."""
    K = kernel_matrix(U, U, variance, lengthscale, kernel)
    n = K.shape[0]
    for k in range(NUGGET_RAISES + 1):
        s2 = nugget * 10.0**k
        try:
            C = np.linalg.cholesky(K + s2 * np.eye(n))
        except np.linalg.LinAlgError:
            continue
        if k == 0:
            return nugget, lml
        log.warning("fitted nugget %.3g does not factorize K + nugget I; raised to %.3g",
                    nugget, s2)
        from scipy.linalg import solve_triangular

        z = solve_triangular(C, r, lower=True, check_finite=False)
        ev = -0.5 * float(z @ z) - float(np.sum(np.log(np.diag(C)))) \
            - 0.5 * n * math.log(2.0 * math.pi)
        return s2, ev
    raise np.linalg.LinAlgError(f"K + nugget I is not positive definite up to nugget "
                                f"{nugget * 10.0**NUGGET_RAISES:.3g}")


#: smallest effective number of training points behind :func:`principal_frame`'s
#: covariance, as a multiple of the dimension d (and at least a fifth of the points)
FRAME_ESS_PER_DIM = 2.0
#: regularization of that covariance (box units): sd added in every direction
FRAME_REG_SD = 0.01


def principal_frame(X: np.ndarray, L: np.ndarray, bounds: np.ndarray,
                    log_offset: np.ndarray | None = None) -> np.ndarray:
    """Orthogonal matrix V (d, d) whose columns are the principal axes of the
    high-likelihood training points, in box-scaled coordinates u = (x - lo) / (hi - lo).

    The covariance is that of the training points weighted by
    w_i ~ exp(beta (L_i - max L)), beta in (0, 1] the largest value giving an
    effective sample size (sum w)^2 / sum w^2 of at least
    max(FRAME_ESS_PER_DIM d, n / 5) (tempering, as in SMC, so that a few top points
    cannot make it degenerate), plus FRAME_REG_SD^2 I. With an active design most
    points lie in the posterior, so this is a rough, widened estimate of the
    posterior's covariance; only its eigenvectors are used. An ARD kernel on
    u V has its length scales along the posterior's principal axes instead of the
    parameter axes, which suits a posterior with strongly correlated (ridge)
    directions; for an isotropic kernel the frame changes nothing. Columns are
    sorted by increasing variance, each signed so that its largest entry is
    positive (deterministic).

    Parameters
    ----------
    X
        (n, d) training inputs in user units (finite values only).
    L
        (n,) their log-likelihoods (finite).
    bounds
        (d, 2) design box.
    log_offset
        (d,) offsets of the GP's log inputs (:func:`warp_inputs`): the frame is that of
        the box-scaled warped inputs. None: linear inputs.

    Returns
    -------
    (d, d) orthogonal matrix.
    """
    X = warp_inputs(np.asarray(X, float), log_offset)
    L = np.asarray(L, float)
    b = warp_inputs(np.asarray(bounds, float).T, log_offset).T
    n, d = X.shape
    U = (X - b[:, 0]) / (b[:, 1] - b[:, 0])
    dL = L - L.max()
    min_ess = min(float(n), max(FRAME_ESS_PER_DIM * d, n / 5.0))

    def ess(beta: float) -> float:
        w = np.exp(beta * dL)
        return float(w.sum() ** 2 / (w * w).sum())

    beta = 1.0
    if ess(1.0) < min_ess:  # ess falls as beta rises: bisect in log beta
        lo, hi = -12.0, 0.0
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ess(10.0**mid) >= min_ess else (lo, mid)
        beta = 10.0**lo
    w = np.exp(beta * dL)
    w /= w.sum()
    R = U - w @ U
    C = (R * w[:, None]).T @ R + FRAME_REG_SD**2 * np.eye(d)
    _, V = np.linalg.eigh(C)
    k = np.argmax(np.abs(V), axis=0)
    return V * np.sign(V[k, np.arange(d)])


#: tolerated excess of a model of L over the likelihood's bound (nats)
OVERSHOOT_NATS = 0.5


def _overshoots(gp: GPSurrogate, bounds: np.ndarray, bound: float, n: int = 4096) -> bool:
    """True when the GP mean of L exceeds ``bound + OVERSHOOT_NATS`` somewhere in the
    box (scrambled Sobol sample of ``n`` points plus the training points)."""
    from bayescalib.inference.design import sobol_design

    Z = np.vstack([sobol_design(np.asarray(bounds, float), n, 12345), gp.X_train])
    return bool(np.max(gp.predict_latent(Z)) > bound + OVERSHOOT_NATS)


#: smallest number of parameters from which ``surrogate.mean: auto`` is the quadratic mean
QUADRATIC_MEAN_FROM_DIM = 3


def resolve_mean(mean: str, dim: int) -> str:
    """The ``surrogate.mean`` setting for a ``dim``-dimensional input: ``"auto"`` is the
    quadratic mean from :data:`QUADRATIC_MEAN_FROM_DIM` dimensions on, else constant."""
    if mean == "auto":
        return "quadratic" if dim >= QUADRATIC_MEAN_FROM_DIM else "constant"
    return mean


#: smallest number of parameters from which ``surrogate.ard: auto`` gives one length scale
#: per input. 2 since issue 17: with the fitted nugget, ridge2d (active design, seeds 0-2)
#: reached Hellinger 0.0003-0.0004 with 52-61 evaluations against 0.0006-0.0010 with 64
#: and one length scale, and the 2-D FSI smoke study (design seed 1) Hellinger <= 0.1
#: from 18 solves against 33 (docs/bench_active.md, "Issue 17: a fitted nugget").
ARD_FROM_DIM = 2
#: smallest number of parameters from which ``surrogate.inputs: auto`` tries log inputs
#: (with one length scale per input; :data:`LOG_INPUTS_NOTE`)
LOG_INPUTS_FROM_DIM = 3


def resolve_ard(ard: bool | str, dim: int) -> bool:
    """The ``surrogate.ard`` setting for a ``dim``-dimensional input: ``"auto"`` is
    one length scale per input from :data:`ARD_FROM_DIM` (2) dimensions on (in 1-D the
    two are the same model)."""
    return dim >= ARD_FROM_DIM if ard == "auto" else bool(ard)


def _discrete_choices(surrogate: dict[str, Any], bounds: np.ndarray, bound: float | None
                      ) -> tuple[list[str], list[bool], list[np.ndarray | None], list[bool]]:
    """The values of the surrogate's discrete choices that a full search fits, for a
    validated ``surrogate`` section and a design box ``bounds`` (d, 2): kernels, outputs
    (warped: the log-misfit), input scales (None: linear, else the log offsets) and frames
    (True: the principal frame, computed from the data when there are at least two
    finite values). ``bound``: the log-likelihood's upper bound (None: unknown)."""
    d = int(np.shape(bounds)[0])
    ard = resolve_ard(surrogate["ard"], d)
    output = surrogate["output"]
    warps = [False] if bound is None or output == "loglik" else \
        [True] if output == "log_misfit" else [False, True]
    if surrogate["kernel"] != "auto":
        kernels = [surrogate["kernel"]]
    elif bound is None:  # uncapped: keep the paper's kernel (smoother ones overshoot more)
        kernels = ["matern32"]
    else:
        kernels = list(KERNELS)
    offsets = log_input_offsets(bounds)
    inputs_cfg = surrogate["inputs"]
    if inputs_cfg == "auto" and (not ard or d < LOG_INPUTS_FROM_DIM):
        inputs_cfg = "linear"  # measured: log inputs cost the 2-D studies solves (LOG_INPUTS_NOTE)
    scales: list[np.ndarray | None] = \
        [None] if offsets is None or inputs_cfg == "linear" else \
        [offsets] if inputs_cfg == "log" else [None, offsets]
    frame = surrogate["frame"]
    frames = [False] if not ard or frame == "axes" else \
        [True] if frame == "principal" else [False, True]
    return kernels, warps, scales, frames


def search_size(surrogate: dict[str, Any], bounds: np.ndarray, *,
                bound_known: bool = True) -> int:
    """Number of candidate models a full search of the discrete choices fits
    (:func:`fit_from_config`), each with ``surrogate["restarts"]`` optimizer starts;
    known from the settings and the design box alone (the study's time guard,
    :mod:`bayescalib.inference.cost`)."""
    kernels, warps, scales, frames = _discrete_choices(
        surrogate, np.asarray(bounds, float), 0.0 if bound_known else None)
    return len(kernels) * len(warps) * len(scales) * len(frames)


def _search_settings(X: np.ndarray, y: np.ndarray, surrogate: dict[str, Any],
                     bounds: np.ndarray, bound: float | None
                     ) -> tuple[dict[str, Any], list[tuple[str, bool, np.ndarray | None,
                                                           np.ndarray | None]]]:
    """The keyword arguments of :func:`fit_gp` shared by every candidate of the surrogate's
    discrete choices, and the candidates (kernel, warp, log_offset, rotation) in the order
    :func:`fit_from_config` fits them (a principal frame computed from ``X``, ``y``)."""
    kw = {"ard": resolve_ard(surrogate["ard"], np.shape(X)[1]),
          "optimizer": surrogate["optimizer"],
          "restarts": surrogate["restarts"], "seed": surrogate["seed"], "bounds": bounds,
          "mean_offset_factor": surrogate["mean_offset_factor"],
          "nugget_factor": surrogate["nugget_factor"], "bound": bound,
          "nugget": surrogate["nugget"], "nugget_floor": surrogate["nugget_floor"],
          "mean": resolve_mean(surrogate["mean"], np.shape(X)[1])}
    kernels, warps, scales, frames = _discrete_choices(surrogate, bounds, bound)
    Xa, ya = np.asarray(X, float), np.asarray(y, float).reshape(-1)
    ok = np.isfinite(ya) & np.all(np.isfinite(Xa), axis=1)
    inputs: list[tuple[np.ndarray | None, np.ndarray | None]] = []
    for log_offset in scales:
        rotations: list[np.ndarray | None] = [None]
        if frames != [False] and ok.sum() >= 2:
            V = principal_frame(Xa[ok], ya[ok], bounds, log_offset)
            rotations = [V if principal else None for principal in frames]
        inputs += [(log_offset, rotation) for rotation in rotations]
    return kw, [(kernel, warp, log_offset, rotation)
                for kernel, warp, (log_offset, rotation) in
                itertools.product(kernels, warps, inputs)]


def _describe(kernel: str, warp: bool, log_offset: np.ndarray | None,
              rotation: np.ndarray | None) -> str:
    return f"{kernel} of {'log-misfit' if warp else 'L'}" + \
        ("" if rotation is None else " (principal axes)") + \
        ("" if log_offset is None else " (log inputs)")


def _fit_candidate(X: np.ndarray, y: np.ndarray, kw: dict[str, Any], bounds: np.ndarray,
                   bound: float | None, candidate: tuple[str, bool, np.ndarray | None,
                                                         np.ndarray | None],
                   warm_start: tuple[float, np.ndarray] | None = None) -> GPSurrogate | None:
    """:func:`fit_gp` of one candidate of the discrete choices; None when the fit fails or
    a model of L overshoots the bound inside the box (:func:`_overshoots`)."""
    kernel, warp, log_offset, rotation = candidate
    what = _describe(*candidate)
    try:
        gp = fit_gp(X, y, warp=warp, kernel=kernel, rotation=rotation,
                    log_offset=log_offset, warm_start=warm_start, **kw)
    except (RuntimeError, np.linalg.LinAlgError) as exc:
        log.warning("surrogate %s: fit failed: %s", what, exc)
        return None
    if bound is not None and not gp.warped and _overshoots(gp, bounds, bound):
        log.info("surrogate %s: rejected, its mean exceeds the likelihood's "
                 "upper bound %.6g inside the box", what, bound)
        return None
    return gp


def _evidence_of_L(gp: GPSurrogate) -> float:
    """The evidence of the log-likelihood values (the warped GP's carried to L by the
    Jacobian of the warping, :func:`fit_from_config`)."""
    return gp.log_marginal_likelihood - (float(np.sum(gp.y_train)) if gp.warped else 0.0)


def surrogate_settings(**settings: Any) -> dict[str, Any]:
    """A validated ``surrogate`` section: ``settings`` (keys of the section, e.g.
    ``kernel="matern32"``) over the schema's defaults; the way from Python to the study's
    surrogate, :func:`fit_from_config` (``fit_from_config(X, y, surrogate_settings(),
    bounds)`` fits what a study with no ``surrogate`` section fits).

    Raises
    ------
    bayescalib.config.ConfigError
        Naming a key the section does not have or a value it does not allow.
    """
    return validate({"surrogate": settings}, "inference", where="surrogate_settings")["surrogate"]


def fit_from_config(X: np.ndarray, y: np.ndarray, surrogate: dict[str, Any],
                    bounds: np.ndarray, *, bound: float | None = None) -> GPSurrogate:
    """:func:`fit_gp` with the settings of a validated ``surrogate`` config section.

    ``surrogate["output"]`` chooses what the GP models when the log-likelihood's
    upper bound ``bound`` is known: ``log_misfit`` (the warped output), ``loglik``
    (L itself, capped at the bound) or ``auto``; ``surrogate["kernel"]`` one of
    :data:`KERNELS` or ``auto``. Every candidate model is fitted and the one with
    the largest evidence *of the log-likelihood values* wins (type-II maximum
    likelihood over the model's discrete choices). The warped model's evidence
    is carried to the units of L by the Jacobian of the warping,
    log p(L) = log p(g) + sum_i log|dg/dL|_i = log p(g) - sum_i g_i (warped GPs,
    Snelson et al. 2004), so all evidences compare like with like. A model of L
    whose mean rises above the bound inside the box (by more than
    ``OVERSHOOT_NATS``, on a Sobol sample) contradicts what is known and is not
    chosen: capping it would leave a plateau of spurious maximal likelihood.
    Without a bound the GP models L with the paper's kernel.

    ``surrogate["frame"]`` chooses the GP's input coordinates when the kernel has
    one length scale per input (``ard``): ``axes`` (the box-scaled parameters),
    ``principal`` (rotated to the principal axes of the high-likelihood training
    points, :func:`principal_frame`) or ``auto`` (both, chosen by the same evidence
    rule). An isotropic kernel does not depend on the rotation, so it keeps ``axes``.

    ``surrogate["inputs"]`` chooses the scale of the inputs: ``linear``, ``log`` (the
    inputs whose box lies in [0, inf) enter as logs, :func:`log_input_offsets`) or
    ``auto``: with one length scale per input (``ard``) in three or more dimensions,
    both, by the same evidence rule (the principal frame is computed in each scale);
    with a single length scale or in one or two dimensions, ``linear`` (see
    :data:`LOG_INPUTS_NOTE`). Without an input that qualifies, ``log``
    and ``auto`` are ``linear``.
    """
    kw, candidates = _search_settings(X, y, surrogate, bounds, bound)
    best, best_ev = None, -math.inf
    for candidate in candidates:
        gp = _fit_candidate(X, y, kw, bounds, bound, candidate)
        if gp is None:
            continue
        ev = _evidence_of_L(gp)
        log.info("surrogate %s: evidence of L %.6g", _describe(*candidate), ev)
        if best is None or ev > best_ev:
            best, best_ev = gp, ev
    if best is None:
        raise RuntimeError("every GP surrogate fit failed")
    if len(candidates) > 1:
        log.info("surrogate chosen: %s of %s%s%s", best.kernel,
                 "log-misfit" if best.warped else "L",
                 "" if best.rotation is None else " (principal axes)",
                 "" if best.log_offset is None else " (log inputs)")
    best.selection, best.selection_n = _SEARCH, best.n_train
    return best



def _matches(candidate: tuple[str, bool, np.ndarray | None, np.ndarray | None],
             previous: GPSurrogate) -> bool:
    """True when ``candidate`` (kernel, warp, log_offset, rotation) makes the same discrete
    choices as ``previous``: kernel, output (log-misfit or L), input scale (log or linear)
    and frame (principal or axes; the rotation itself is recomputed from current data)."""
    kernel, warp, log_offset, rotation = candidate
    return (kernel == previous.kernel and bool(warp) == previous.warped
            and (log_offset is None) == (previous.log_offset is None)
            and (rotation is None) == (previous.rotation is None))


#: the refit of :func:`fit_round` starts its first optimizer run at the previous round's
#: kernel variance and length scales (else at the default start, as the full search)
REFIT_WARM_START = True


def fit_round(X: np.ndarray, y: np.ndarray, surrogate: dict[str, Any], bounds: np.ndarray, *,
              bound: float | None = None, previous: GPSurrogate | None = None) -> GPSurrogate:
    """The surrogate of one round of the active design: :func:`fit_from_config` (the full
    search of the discrete choices: kernel x output x input scale x frame) only when the
    training set has grown enough since the last full search, else a refit of the
    previous round's choice.

    Rule (``surrogate["reselect_growth"]`` = f >= 0). With n the number of finite
    training values now and n_s that of the last full search (``previous.selection_n``),
    the candidates are searched in full when

        previous is None, f = 0, n_s is unknown, or n >= (1 + f) n_s,

    and when the previous choice is not among the candidates of ``surrogate`` (the
    settings changed). Otherwise only the previous choice is fitted, on all current data
    (the principal frame, if chosen, recomputed from them), its first optimizer start at
    the previous kernel variance and length scales, and fitted nugget (warm start: with a
    fitted nugget one start more, before the default ones; the other ``restarts - 1``
    starts as in :func:`fit_gp`). A refit that fails, or a model of L whose mean exceeds
    the bound inside the box (:func:`_overshoots`), falls back to the full search. With
    f = 0 the result is that of :func:`fit_from_config`, bit for bit.

    The discrete choices are chosen by the evidence among models fitted to the same
    data (type-II maximum likelihood); between searches the evidences of the candidates
    change slowly as a design grows by small batches, so re-deciding them every round
    mostly refits the same choice. The refit keeps the choice's continuous
    hyperparameters (variance, length scales, quadratic mean) optimal for current data.

    Parameters
    ----------
    X
        (n, d) training inputs in user units.
    y
        (n,) their log-likelihoods (non-finite: failed, left out).
    surrogate
        A validated ``surrogate`` config section.
    bounds
        (d, 2) design box.
    bound
        Upper bound of the log-likelihood; None: unknown.
    previous
        The previous round's surrogate (None: round 0).

    Returns
    -------
    GPSurrogate
        With ``selection`` ``"search"`` (and ``selection_n`` = its n) after a full search,
        ``"refit"`` (``selection_n`` carried over from ``previous``) after a refit.
    """
    if previous is None:
        return fit_from_config(X, y, surrogate, bounds, bound=bound)
    growth = float(surrogate["reselect_growth"])
    ya = np.asarray(y, float).reshape(-1)
    n = int((np.isfinite(ya) & np.all(np.isfinite(np.asarray(X, float)), axis=1)).sum())
    n_s = int(previous.selection_n)
    if growth <= 0 or n_s < 1 or n >= (1.0 + growth) * n_s:
        if growth > 0 and n_s >= 1:
            log.info("surrogate: %d training values, %.3g times the %d of the last search "
                     "of the discrete choices: searched again", n, n / n_s, n_s)
        return fit_from_config(X, y, surrogate, bounds, bound=bound)
    kw, candidates = _search_settings(X, y, surrogate, bounds, bound)
    same = [c for c in candidates if _matches(c, previous)]
    if not same or kw["ard"] != previous.ard or kw["mean"] != previous.mean_function \
            or (kw["nugget"] == "fit") != previous.nugget_fitted:
        log.info("surrogate: the previous choice (%s) is not among the candidates of the "
                 "settings: full search", _describe(previous.kernel, previous.warped,
                                                    previous.log_offset, previous.rotation))
        return fit_from_config(X, y, surrogate, bounds, bound=bound)
    candidate = same[0]
    warm = (float(previous.variance), np.array(previous.lengthscale, float),
            float(previous.nugget) if previous.nugget_fitted else None) \
        if REFIT_WARM_START else None
    gp = _fit_candidate(X, y, kw, bounds, bound, candidate, warm_start=warm)
    if gp is None:
        log.info("surrogate: the refit of %s was rejected: full search",
                 _describe(*candidate))
        return fit_from_config(X, y, surrogate, bounds, bound=bound)
    gp.selection, gp.selection_n = _REFIT, n_s
    log.info("surrogate: %s refitted on %d values (choices searched at %d; next search "
             "from %d), evidence of L %.6g", _describe(*candidate), n, n_s,
             math.ceil((1.0 + growth) * n_s), _evidence_of_L(gp))
    return gp
