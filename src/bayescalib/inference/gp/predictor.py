"""The fitted GP surrogate of the log-likelihood and its fast batched predictor.

Prediction (eq. posterior_gp)
    mean(x*) = m + k*^T (K + sigma_n^2 I)^{-1} (L - m)
    var(x*)  = k(x*, x*) - k*^T (K + sigma_n^2 I)^{-1} k*     (latent, noise-free)

:class:`GPSurrogate` caches the Cholesky factor of K + sigma_n^2 I and the
weights alpha = (K + sigma_n^2 I)^{-1} (L - m) and evaluates the formulas above
as plain batched array algebra in float64 -- this is what the SMC calls
millions of times. It equals GPy's ``predict_noiseless`` to round-off (tested
to 1e-8 relative); ``gpy_model()`` rebuilds the GPy model with the stored
hyperparameters for comparison. With the log-misfit output the latent mean and
variance are mapped to the likelihood scale (:mod:`bayescalib.inference.gp.warping`).
The prior mean m is the constant ``mean_const`` or the misfit-shaped quadratic
(:mod:`bayescalib.inference.gp.mean`); the inputs pass the log inputs, box scaling and
frame (:mod:`bayescalib.inference.gp.inputs`) first.

* CPU (``device="cpu"``): NumPy. Squared distances come from one matrix
  product of augmented inputs [a, |a|^2, 1] @ [-2b, 1, |b|^2]^T with
  sqrt(3)/l folded into the input scaling and s^2 into the weights. Rows are
  processed in chunks small enough that each (chunk, n) kernel block stays in
  cache (the algebra is memory-bound) and that the distance product stays
  below OpenBLAS's multithreading threshold (threaded small products were
  much slower on a loaded machine). ``threads`` > 1 spreads chunks
  over a thread pool (default 1: on a small machine shared with forward
  solves, extra threads were slower). The kernel rows are computed in per-thread
  preallocated arrays (bitwise the values of fresh temporaries, faster).
  The measurements behind these choices: ``docs/surrogate.md``.
* GPU (``device="auto"`` with CUDA, or any torch device; ``"torch:cpu"`` for
  testing): the same algebra in torch, in chunks of at most
  ``chunk_entries`` kernel entries. Where no GPU can exist, ``"auto"`` decides for
  NumPy without importing torch (:func:`gpu_possible`).
* Several GPs on the same training inputs (the output emulator's coordinates,
  :mod:`bayescalib.inference.emulator`) on a torch device: :class:`StackedGPs`
  evaluates them in one batched pass, (k, chunk, n) kernel blocks and one batched
  triangular solve, instead of k passes of their own (on a GPU each pass is a string
  of small kernel launches and a synchronizing copy back to the host).

The surrogate file (:meth:`GPSurrogate.save` / :meth:`GPSurrogate.load`) is written and
read by :mod:`bayescalib.inference.gp.store`.
"""

from __future__ import annotations

import math
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.inference.gp.inputs import frame_extent, warp_inputs
from bayescalib.inference.gp.kernels import KERNELS, _unit_kernel_from_t2, kernel_matrix
from bayescalib.inference.gp.mean import (
    QUAD_CENTER_MARGIN,
    _quadratic_mapping_class,
    quadratic_mean,
)
from bayescalib.inference.gp.warping import (
    latent_variance_to_loglik,
    log_misfit,
    loglik_from_log_misfit,
)

__all__ = ["GPSurrogate", "StackedGPs", "gpu_possible"]

_GEMM_SINGLE_THREAD_MNK = 2**18


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
    torch, whose import costs seconds in every job that loads a surrogate:
    ``docs/surrogate.md``). True elsewhere, and where torch is already imported."""
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
#: one that refitted the previous round's choice
#: (:func:`~bayescalib.inference.gp.selection.fit_round`)
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
        :func:`~bayescalib.inference.gp.fit.fit_gp`), False when fixed by the rule of
        ``nugget_factor``.
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
        :func:`~bayescalib.inference.gp.inputs.principal_frame`); None: u = (x - shift) / scale.
    log_offset : (d,) or None: input k enters as log(x_k + log_offset_k) before the
        scaling (``shift`` and ``scale`` are then in those units); NaN entries (or
        None) keep x_k linear (:meth:`warp_inputs`).
    mean_function : ``"constant"`` (the prior mean is ``mean_const``) or
        ``"quadratic"`` (the misfit-shaped mean of
        :func:`~bayescalib.inference.gp.mean.quadratic_mean`;
        ``mean_const`` is then NaN and unused).
    mean_center, mean_factor : centre c (d,) and upper-triangular factor R (d, d) of the
        quadratic mean's Hessian R^T R, in the GP's input frame (:meth:`scale_inputs`);
        None for a constant mean.
    mean_misfit_min : misfit phi0 (nats) of the quadratic mean at its centre.
    mean_top : the value the quadratic mean of a GP of L falls from (the bound B, or
        max(L) + range(L) without one); NaN for the log-misfit GP.
    selection : how the discrete choices (kernel, output, input scale, frame) were made:
        ``"search"`` (every candidate fitted, the largest evidence kept:
        :func:`~bayescalib.inference.gp.selection.fit_from_config`, or one given choice:
        :func:`~bayescalib.inference.gp.fit.fit_gp`) or ``"refit"`` (the previous round's
        choice refitted, :func:`~bayescalib.inference.gp.selection.fit_round`).
    selection_n : number of training values at the last full search of those choices
        (-1: unknown, e.g. a file written before it was recorded).
    selection_reason : why the choices were searched or refitted
        (:func:`~bayescalib.inference.gp.selection.fit_round`: ``"round 0"``,
        ``"growth"``, ``"mispredicted"``, ``"settings changed"``, ``"refit rejected"``
        for a search; ``"predicted well"``, ``"no new value in the region"`` for a
        refit); ``""``: not recorded (a search outside :func:`fit_round`, or a file
        written before the record).
    selection_error : the largest error (nats) of the previous round's surrogate at the
        new values in the posterior region, which decided between refit and search
        (NaN: not measured).
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
    selection_reason: str = ""
    selection_error: float = float("nan")
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
            return loglik_from_log_misfit(g, self.bound)
        if self.bound is not None:
            return np.minimum(g, self.bound)
        return g

    def latent_from_loglik(self, L: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`loglik_from_latent` (values above the bound map to g = 0)."""
        L = np.asarray(L, float)
        if not self.warped:
            return L
        return log_misfit(L, self.bound)

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
        memory pass fewer per operation than fresh temporaries, faster in the SMC
        (``docs/surrogate.md``), bitwise the same values): the result is valid until the
        thread's next call."""
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
        # small GEMM is much slower than a single-threaded one (docs/surrogate.md).
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
        return self.loglik_from_latent(g), latent_variance_to_loglik(g, var_g)

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
        from bayescalib.inference.gp.fit import _build_gpy

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
            mu, var = self.loglik_from_latent(mu), latent_variance_to_loglik(mu, var)
        return (mu, var) if return_var else mu

    # ------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the surrogate to HDF5 (atomically): data, scaling, hyperparameters, factors
        (the layout of :mod:`bayescalib.inference.gp.store`)."""
        from bayescalib.inference.gp.store import save

        save(self, path)

    def write_group(self, f) -> None:
        """Write the surrogate's data into the open h5py file or group ``f`` (the layout
        of :meth:`save`, without the file header: an emulator stores one per output
        coordinate, :mod:`bayescalib.inference.emulator`;
        :func:`bayescalib.inference.gp.store.write_group`)."""
        from bayescalib.inference.gp.store import write_group

        write_group(self, f)

    @classmethod
    def load(cls, path: str | Path, device: str = "auto") -> GPSurrogate:
        """Read a surrogate written by :meth:`save`; predictions are reproduced exactly
        (:func:`bayescalib.inference.gp.store.load`)."""
        from bayescalib.inference.gp.store import load

        return load(path, device=device)

    @classmethod
    def read_group(cls, f, device: str = "auto") -> GPSurrogate:
        """Read a surrogate from the open h5py file or group ``f`` (:meth:`write_group`;
        :func:`bayescalib.inference.gp.store.read_group`)."""
        from bayescalib.inference.gp.store import read_group

        return read_group(f, device=device)

    def loo_residuals(self) -> np.ndarray:
        """Leave-one-out residuals y_i - mean_{-i}(x_i) = alpha_i / [(K + s_n^2 I)^{-1}]_ii, (n,).

        Closed form (Rasmussen & Williams 2006, eq. 5.12) at fixed hyperparameters.
        """
        from scipy.linalg import cho_solve

        Kinv = cho_solve((self.chol, True), np.eye(self.n_train))
        return self.alpha / np.diag(Kinv)


class StackedGPs:
    """Several GPs with the same training inputs, evaluated in one batched torch pass.

    The emulator's coordinate GPs (:mod:`bayescalib.inference.emulator`) share their
    design points but not their hyperparameters. On a torch device each
    :meth:`GPSurrogate.predict_latent` is a string of small kernel launches and a copy
    back to the host; stacked, the k GPs' kernel blocks (k, c, n), their means and the
    variances' triangular solves are batched, so a call costs about one GP's launches.
    The algebra is :meth:`GPSurrogate._predict_torch`'s, GP by GP (equal to round-off).

    Parameters
    ----------
    gps
        The GPs; :meth:`compatible` must hold.
    """

    def __init__(self, gps: list[GPSurrogate]) -> None:
        if not self.compatible(gps):
            raise ValueError("the GPs cannot be stacked (StackedGPs.compatible)")
        self.gps = list(gps)
        self._t: dict[str, Any] | None = None

    @staticmethod
    def compatible(gps: list[GPSurrogate]) -> bool:
        """True when the GPs can be evaluated as one: at least two, all on the same torch
        device (not the NumPy ``"cpu"``), with the same training inputs, kernel and input
        warp, a constant prior mean and latent outputs (no bound, no warping)."""
        if len(gps) < 2 or not all(isinstance(g, GPSurrogate) for g in gps):
            return False
        g0 = gps[0]
        if g0.device == "cpu":
            return False
        lo0 = g0.log_offset
        for g in gps:
            if (g.device != g0.device or g.kernel != g0.kernel or g.dim != g0.dim
                    or g.mean_function != "constant" or g.bound is not None or g.warped
                    or g.n_train != g0.n_train):
                return False
            lo = g.log_offset
            if (lo is None) != (lo0 is None) or (
                    lo is not None and not np.array_equal(lo, lo0, equal_nan=True)):
                return False
            if g is not g0 and not np.array_equal(g.X_train, g0.X_train):
                return False
        return True

    def _tensors(self) -> dict[str, Any]:
        if self._t is None:
            torch = _torch()
            dev = self.gps[0]._torch_device

            def t(a):
                return torch.as_tensor(np.asarray(a, float), dtype=torch.float64, device=dev)

            self._t = {
                "shift": t(np.stack([g.shift for g in self.gps])[:, None, :]),
                "map": t(np.stack([g._input_map() for g in self.gps])),
                "B": t(np.stack([g.scale_inputs(g.X_train) / g.lengthscale
                                 for g in self.gps])),
                "alpha": t(np.stack([g.alpha for g in self.gps])[:, :, None]),
                "L": t(np.stack([g.chol for g in self.gps])),
                "s2": t(np.array([g.variance for g in self.gps])),
                "mean": t(np.array([g.mean_const for g in self.gps])),
            }
            self._t["Bsq"] = (self._t["B"] ** 2).sum(2)
        return self._t

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Latent means and variances of every GP at X (M, d) in user units: two
        (M, k) arrays (column j: GP j's :meth:`GPSurrogate.predict_latent`)."""
        torch = _torch()
        g0 = self.gps[0]
        X = np.atleast_2d(np.asarray(X, float))
        if X.ndim != 2 or X.shape[1] != g0.dim:
            raise ValueError(f"expected inputs of shape (M, {g0.dim}), got {X.shape}")
        c = self._tensors()
        k, M, n = len(self.gps), X.shape[0], max(g0.n_train, 1)
        mean = np.empty((M, k))
        var = np.empty((M, k))
        ck2 = KERNELS[g0.kernel][0] ** 2
        chunk = max(1, g0.chunk_entries // (k * n))
        with torch.no_grad():
            Xt = torch.as_tensor(g0.warp_inputs(X), dtype=torch.float64,
                                 device=g0._torch_device)
            for s in range(0, M, chunk):
                A = torch.matmul(Xt[None, s : s + chunk] - c["shift"], c["map"])  # (k, c, d)
                r2 = ((A * A).sum(2)[:, :, None] + c["Bsq"][:, None, :]
                      - 2.0 * torch.matmul(A, c["B"].transpose(1, 2)))
                t2 = torch.clamp_min_(r2, 0.0).mul_(ck2)
                if g0.kernel == "rbf":
                    K = torch.exp(t2.neg_())
                else:
                    t = torch.sqrt(t2)
                    poly = 1.0 + t + (t2 / 3.0 if g0.kernel == "matern52" else 0.0)
                    K = poly.mul_(torch.exp(t.neg()))
                K.mul_(c["s2"][:, None, None])  # (k, c, n)
                m = torch.matmul(K, c["alpha"])[:, :, 0] + c["mean"][:, None]
                V = torch.linalg.solve_triangular(c["L"], K.transpose(1, 2), upper=False)
                v = torch.clamp_min(c["s2"][:, None] - (V * V).sum(1), 0.0)
                mean[s : s + chunk] = m.T.cpu().numpy()
                var[s : s + chunk] = v.T.cpu().numpy()
        return mean, var
