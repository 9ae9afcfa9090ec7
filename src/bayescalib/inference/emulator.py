"""Emulator of the model's outputs, and the likelihood computed from it.

Why
---
The paper's surrogate (:mod:`bayescalib.inference.gp`) is a GP of the scalar
log-likelihood L(x) = -1/2 |y - u(x)|^2 / sigma^2 + const. When the data are
informative, L falls by thousands of nats across the prior box while the posterior
lives in a region a few nats deep: a stationary GP of L must be accurate to a fraction
of a nat inside a thin shell of a steep surface. In seven dimensions it is not
(``docs/bench_active.md``: on ``hetero7d`` the active design's posterior stays 2-10
reference sd off after 200 evaluations, the GP missing new evaluations by tens to
thousands of nats). The model's outputs u(x) themselves are smooth and of modest
range; the sharpness of L comes only from the squared norm. Emulating u(x) and
computing L from the emulated outputs keeps that structure exact (calibration with
high-dimensional output, Higdon, Gattiker, Williams & Rightley 2008; the emulator's
uncertainty integrated out as in Kennedy & O'Hagan 2001).

Method
------
Outputs and data are given in noise units (divided by the observation noise sd), so
that the likelihood is L(x) = offset - 1/2 |y - u(x)|^2.

1. **Principal outputs** (:func:`principal_outputs`). The training outputs U (n, m)
   are centred, u = ubar + Phi^T a + t, with Phi (k, m) the leading right singular
   vectors (orthonormal rows) and a = Phi (u - ubar) the coordinates. k is the smallest
   number whose discarded energy per training point, sum_{j>k} S_j^2 / n, is at most
   ``energy_tol`` (noise units squared: 0.01 means the discarded part t would move L
   by about 0.005 nats on average), at most ``max_components`` and n - 1.
2. **One GP per coordinate** (:func:`fit_output_emulator`): a_j(x) ~ GP with zero
   mean (the coordinates are centred), ARD Matern 5/2 kernel (the outputs are smooth)
   on the box-scaled inputs, log inputs where they qualify and raise the leading
   coordinate's evidence (the rule of ``surrogate.inputs: auto``), fitted nugget.
3. **The likelihood, emulator uncertainty integrated out** (:class:`EmulatedLikelihood`).
   With the coordinates a ~ N(ahat(x), diag(s^2(x))) and c = Phi (y - ubar),

       L(x) = offset - 1/2 |P_perp (y - ubar)|^2
              - 1/2 sum_j [ (c_j - ahat_j)^2 / (1 + s_j^2) + log(1 + s_j^2) ],

   the Gaussian marginal likelihood of y given x (noise covariance I + Phi^T S Phi;
   Kennedy & O'Hagan 2001, eq. for the code uncertainty). Where the emulator is
   unsure, its variance widens the likelihood instead of letting a guess pass as
   data: the posterior is honest about how little the design has seen there. L never
   exceeds ``offset`` (the bound of the Gaussian log-likelihood, issue 17's
   requirement), by construction. The discarded part t is the same for every x in
   this formula (a constant); ``discarded`` reports its size on the design.
4. **Its uncertainty** (for acquisitions): the plug-in quadratic -1/2 sum (c_j - a_j)^2
   has, under a ~ N(ahat, diag(s^2)), the variance sum_j [(c_j - ahat_j)^2 s_j^2 +
   s_j^4 / 2] (exact for Gaussian a).

The emulated likelihood has the interface of the log-likelihood surrogate that SMC
calls (``predict(X)``, ``predict(X, return_var=True)``).

Design: the rounds of :mod:`bayescalib.inference.rounds` (``surrogate.target:
outputs``; :func:`bayescalib.inference.rounds.calibrate_outputs` in memory), whose
batches are equally weighted draws of the current posterior, each round's draws both
its posterior check (the stop rule's last test in :mod:`bayescalib.inference.active`)
and the next design points: where the posterior lives is where the emulator must be
right. Measured on the 7-D benchmark ``hetero7d``: ``docs/bench_active.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["EmulatedLikelihood", "OutputEmulator", "fit_output_emulator", "load_surrogate",
           "principal_outputs"]


def principal_outputs(U: np.ndarray, *, energy_tol: float = 1e-2,
                      max_components: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Centre the outputs and keep their leading principal directions.

    Parameters
    ----------
    U
        (n, m) training outputs in noise units.
    energy_tol
        Largest discarded energy per training point, sum_{j>k} S_j^2 / n (noise units
        squared).
    max_components
        Upper limit of k (also at most n - 1 and m).

    Returns
    -------
    mean : (m,) the outputs' mean ubar.
    basis : (k, m) orthonormal rows Phi.
    coords : (n, k) the coordinates a = (U - ubar) Phi^T.
    discarded : float, the discarded energy per training point.
    """
    U = np.atleast_2d(np.asarray(U, float))
    n, m = U.shape
    if n < 2:
        raise ValueError(f"principal_outputs needs at least 2 training outputs, got {n}")
    if energy_tol < 0:
        raise ValueError(f"energy_tol must be >= 0, got {energy_tol}")
    mean = U.mean(axis=0)
    _, S, Vt = np.linalg.svd(U - mean, full_matrices=False)
    tail = np.concatenate([np.cumsum((S**2)[::-1])[::-1], [0.0]]) / n  # tail[k] = sum_{j>=k}
    k_max = max(1, min(int(max_components), n - 1, m, S.size))
    k = next((j for j in range(1, k_max + 1) if tail[j] <= energy_tol), k_max)
    basis = Vt[:k]
    return mean, basis, (U - mean) @ basis.T, float(tail[k])


@dataclass
class OutputEmulator:
    """Emulator of a model's outputs: principal directions and one GP per coordinate.

    Attributes
    ----------
    mean : (m,) mean output ubar (noise units).
    basis : (k, m) orthonormal principal directions Phi.
    components : k :class:`~bayescalib.inference.gp.predictor.GPSurrogate`, the GP of each
        coordinate a_j(x).
    discarded : discarded energy per training point (noise units squared).
    n_train : number of training points.
    log_inputs : whether the inputs that qualify entered as logs.
    stack : on a torch device, evaluate the coordinate GPs in one batched pass
        (:meth:`predict`); False: one after the other (a comparison of the two,
        ``benchmarks/bench_gpu.py``).
    """

    mean: np.ndarray
    basis: np.ndarray
    components: list[Any]
    discarded: float
    n_train: int
    log_inputs: bool = False
    info: dict[str, Any] = field(default_factory=dict)
    stack: bool = True
    _stack: Any = field(default=None, init=False, repr=False, compare=False)
    _stack_key: tuple = field(default=(), init=False, repr=False, compare=False)

    @property
    def n_components(self) -> int:
        return int(self.basis.shape[0])

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Coordinates' posterior means and variances at X (M, d): two (M, k) arrays.

        On a torch device (a GPU) the coordinate GPs, which share their design points,
        are evaluated in one batched pass
        (:class:`~bayescalib.inference.gp.predictor.StackedGPs`); on the NumPy device one
        after the other."""
        X = np.atleast_2d(np.asarray(X, float))
        stack = self._stacked()
        if stack is not None:
            a, v = stack.predict(X)
            return a, np.maximum(v, 0.0)
        a = np.empty((X.shape[0], self.n_components))
        v = np.empty_like(a)
        for j, gp in enumerate(self.components):
            a[:, j], v[:, j] = gp.predict(X, return_var=True)
        return a, np.maximum(v, 0.0)

    def _stacked(self) -> Any:
        """The coordinate GPs stacked for one batched torch pass, or None (NumPy device,
        or GPs that cannot be stacked); built once per set of components."""
        from bayescalib.inference.gp.predictor import StackedGPs

        key = tuple((id(g), getattr(g, "device", None)) for g in self.components)
        if self._stack_key != key:
            self._stack_key = key
            self._stack = (StackedGPs(self.components)
                           if self.stack and StackedGPs.compatible(self.components) else None)
        return self._stack

    def predict_outputs(self, X: np.ndarray) -> np.ndarray:
        """Emulated outputs ubar + a Phi at X: (M, m), noise units."""
        a, _ = self.predict(X)
        return self.mean + a @ self.basis


def _fit_coordinate(X, a, bounds, log_offset, *, kernel: str, restarts: int, seed: int,
                    nugget_floor: float):
    from bayescalib.inference.gp import fit_gp

    a = np.asarray(a, float)
    span = float(np.ptp(a)) or 1.0
    # fit_gp's constant mean is min(y) - f (max(y) - min(y)); f = min(y) / range puts it
    # at 0, the coordinates' mean (they are centred)
    return fit_gp(X, a, ard=True, restarts=restarts, seed=seed, bounds=bounds,
                  mean="constant", mean_offset_factor=float(a.min()) / span, kernel=kernel,
                  log_offset=log_offset, nugget="fit", nugget_floor=nugget_floor,
                  device="cpu")


def fit_output_emulator(X: np.ndarray, U: np.ndarray, bounds: np.ndarray, *,
                        energy_tol: float = 1e-2, max_components: int = 30,
                        kernel: str = "matern52", restarts: int = 2, seed: int = 0,
                        inputs: str = "auto", nugget_floor: float = 1e-6,
                        failed: np.ndarray | None = None) -> OutputEmulator:
    """Fit the output emulator (module docstring, steps 1-2).

    Parameters
    ----------
    X
        (n, d) design points in user units.
    U
        (n, m) their outputs in noise units; rows with a non-finite entry (failed
        solves) are left out.
    bounds
        (d, 2) design box (input scaling).
    energy_tol, max_components
        :func:`principal_outputs`.
    kernel
        Kernel of every coordinate's GP (:data:`~bayescalib.inference.gp.kernels.KERNELS`).
    restarts, seed
        Optimizer starts of each GP fit, and their seed.
    inputs
        ``linear``, ``log`` (inputs whose box lies in [0, inf) as logs) or ``auto``
        (both fitted to the leading coordinate; the larger evidence decides for all).
    nugget_floor
        Floor of each coordinate GP's fitted nugget (noise units squared).
    failed
        (n,) bool: the rows whose failure marks where the model cannot be solved
        (:mod:`bayescalib.inference.feasibility`; kept by the first coordinate's GP,
        ``X_failed``, and used by :meth:`EmulatedLikelihood.loglik`). None: every row
        with a non-finite output.
    """
    from bayescalib.inference.gp import log_input_offsets

    X = np.atleast_2d(np.asarray(X, float))
    U = np.atleast_2d(np.asarray(U, float))
    if X.shape[0] != U.shape[0]:
        raise ValueError(f"X has {X.shape[0]} rows and U {U.shape[0]}: one output row per point")
    ok = np.all(np.isfinite(U), axis=1)
    marks = ~ok if failed is None else np.asarray(failed, bool) & ~ok
    X_failed = X[marks & np.all(np.isfinite(X), axis=1)]
    X, U = X[ok], U[ok]
    mean, basis, coords, discarded = principal_outputs(U, energy_tol=energy_tol,
                                                       max_components=max_components)
    offsets = log_input_offsets(np.asarray(bounds, float))
    qualifies = offsets is not None and bool(np.any(np.isfinite(offsets)))
    if inputs not in ("linear", "log", "auto"):
        raise ValueError(f"inputs must be 'linear', 'log' or 'auto', got {inputs!r}")
    use_log = qualifies and inputs != "linear"
    kw = {"kernel": kernel, "restarts": restarts, "seed": seed, "nugget_floor": nugget_floor}
    first = _fit_coordinate(X, coords[:, 0], bounds, offsets if use_log else None, **kw)
    if qualifies and inputs == "auto":
        linear = _fit_coordinate(X, coords[:, 0], bounds, None, **kw)
        if linear.log_marginal_likelihood > first.log_marginal_likelihood:
            first, use_log = linear, False
    comps = [first] + [
        _fit_coordinate(X, coords[:, j], bounds, offsets if use_log else None, **kw)
        for j in range(1, basis.shape[0])]
    first.X_failed = X_failed if len(X_failed) else None  # the emulator's failed region
    return OutputEmulator(mean=mean, basis=basis, components=comps, discarded=discarded,
                          n_train=int(X.shape[0]), log_inputs=bool(use_log),
                          info={"n_failed": int((~ok).sum())})


class EmulatedLikelihood:
    """The Gaussian log-likelihood of data ``y`` computed from an :class:`OutputEmulator`,
    its uncertainty integrated out (module docstring, steps 3-4).

    Parameters
    ----------
    emulator
        The fitted output emulator.
    y
        (m,) observed data in noise units.
    offset
        The likelihood's value at a perfect fit (its upper bound), e.g.
        -m log sigma - m/2 log(2 pi) for the Gaussian density in user units; 0 gives
        -1/2 |y - u|^2.
    """

    def __init__(self, emulator: OutputEmulator, y: Sequence[float] | np.ndarray,
                 offset: float = 0.0) -> None:
        self.emulator = emulator
        y = np.asarray(y, float).reshape(-1)
        if y.shape[0] != emulator.mean.shape[0]:
            raise ValueError(f"y has {y.shape[0]} values, the emulator {emulator.mean.shape[0]} "
                             "outputs")
        self.y = y
        r = y - emulator.mean
        self.c = emulator.basis @ r
        self.perp = float(max(r @ r - self.c @ self.c, 0.0))
        self.offset = float(offset)
        self.bound = self.offset - 0.5 * self.perp

    def predict(self, X: np.ndarray, return_var: bool = False):
        """Log-likelihood at X (M, d): the marginal over the emulator, (M,); with
        ``return_var`` also the variance of the plug-in log-likelihood (M,)."""
        a, s2 = self.emulator.predict(X)
        d2 = (self.c - a) ** 2
        L = self.bound - 0.5 * np.sum(d2 / (1.0 + s2) + np.log1p(s2), axis=1)
        if not return_var:
            return L
        return L, np.sum(d2 * s2 + 0.5 * s2 * s2, axis=1)

    __call__ = predict

    def loglik(self, X: np.ndarray) -> np.ndarray:
        """The log-likelihood the sampler targets, (M,): :meth:`predict`'s, and -inf
        where the failed solves mark the model infeasible (kept by the first
        coordinate's GP, :meth:`bayescalib.inference.gp.predictor.GPSurrogate.infeasible`)."""
        L = self.predict(X)
        first = self.emulator.components[0]
        if first.X_failed is not None:
            L = np.where(first.infeasible(X), -np.inf, L)
        return L

    @property
    def n_failed(self) -> int:
        """Failed solves that mark where the model cannot be solved."""
        return self.emulator.components[0].n_failed

    def plug_in(self, X: np.ndarray) -> np.ndarray:
        """-1/2 |y - u_hat(x)|^2 + offset with the emulator's mean outputs (no
        uncertainty), (M,): the likelihood of the emulated model itself."""
        a, _ = self.emulator.predict(X)
        return self.bound - 0.5 * np.sum((self.c - a) ** 2, axis=1)

    # ------------------------------------------- the surrogate interface of the stages
    @property
    def n_train(self) -> int:
        return int(self.emulator.n_train)

    @property
    def n_excluded(self) -> int:
        """Training rows left out (failed solves: outputs not finite)."""
        return int(self.emulator.info.get("n_failed", 0))

    @property
    def threads(self) -> int:
        comps = self.emulator.components
        return int(comps[0].threads) if comps else 1

    @threads.setter
    def threads(self, value: int) -> None:
        """Threads of every coordinate GP's chunked prediction (the same chunks, so
        the values are those of one thread)."""
        for gp in self.emulator.components:
            gp.threads = max(1, int(value))

    @property
    def hyperparameters(self) -> dict[str, Any]:
        """What was fitted, JSON-serializable: the number of principal outputs, the
        discarded energy, the inputs' scale and each coordinate GP's hyperparameters."""
        em = self.emulator
        return {"output": "outputs", "n_outputs": int(em.mean.shape[0]),
                "components": em.n_components, "discarded": float(em.discarded),
                "log_inputs": bool(em.log_inputs), "offset": self.offset,
                "bound": self.bound,
                "coordinates": [gp.hyperparameters for gp in em.components]}

    def save(self, path) -> None:
        """Write the emulator and the data to HDF5 atomically (kind ``emulator`` of
        :mod:`bayescalib.io.header`): ``/mean (m,)``, ``/basis (k, m)``, ``/y (m,)``,
        one group ``/coordinates/<j>`` per coordinate GP
        (:meth:`~bayescalib.inference.gp.predictor.GPSurrogate.write_group`), attributes
        ``offset``, ``discarded``, ``n_train``, ``n_failed``, ``log_inputs``."""
        import h5py

        from bayescalib.io._atomic_write import atomic_path
        from bayescalib.io.header import write_header

        em = self.emulator
        with atomic_path(path, suffix=".h5") as tmp, h5py.File(tmp, "w") as f:
            write_header(f, "emulator")
            f["mean"] = em.mean
            f["basis"] = em.basis
            f["y"] = self.y
            f.attrs["offset"] = self.offset
            f.attrs["discarded"] = float(em.discarded)
            f.attrs["n_train"] = int(em.n_train)
            f.attrs["n_failed"] = int(em.info.get("n_failed", 0))
            f.attrs["log_inputs"] = bool(em.log_inputs)
            g = f.create_group("coordinates")
            for j, gp in enumerate(em.components):
                gp.write_group(g.create_group(str(j)))

    @classmethod
    def load(cls, path, device: str = "cpu") -> EmulatedLikelihood:
        """Read a file written by :meth:`save`; predictions are reproduced exactly."""
        import h5py

        from bayescalib.inference.gp import GPSurrogate
        from bayescalib.io.header import validate_header

        with h5py.File(path, "r") as f:
            validate_header(f, "emulator", path)
            g = f["coordinates"]
            comps = [GPSurrogate.read_group(g[str(j)], device=device) for j in range(len(g))]
            em = OutputEmulator(mean=f["mean"][()], basis=f["basis"][()], components=comps,
                                discarded=float(f.attrs["discarded"]),
                                n_train=int(f.attrs["n_train"]),
                                log_inputs=bool(f.attrs["log_inputs"]),
                                info={"n_failed": int(f.attrs["n_failed"])})
            return cls(em, f["y"][()], offset=float(f.attrs["offset"]))


def load_surrogate(path, device: str = "auto"):
    """The surrogate a ``train_surrogate`` job wrote, whatever its kind: a
    :class:`~bayescalib.inference.gp.predictor.GPSurrogate` of the log-likelihood
    (``surrogate.target: loglik``) or an :class:`EmulatedLikelihood`
    (``surrogate.target: outputs``). Both give ``predict(X)`` and
    ``predict(X, return_var=True)`` of the log-likelihood."""
    import h5py

    from bayescalib.inference.gp import GPSurrogate
    from bayescalib.io.header import FORMATS

    with h5py.File(path, "r") as f:
        kind = f.attrs.get("format")
    kind = kind.decode() if isinstance(kind, bytes) else kind
    if kind == FORMATS["emulator"][0]:
        return EmulatedLikelihood.load(path, device=device)
    return GPSurrogate.load(path, device=device)
