"""One GP fit: the hyperparameters of one surrogate model by its evidence (paper Sec. 3.2,
App. D).

:func:`fit_gp` fits one model, every choice of it given (kernel, output transform, input
scale and frame, mean, nugget); the search over those choices is
:mod:`bayescalib.inference.gp.selection`.

Training (eq. gploglikeli)
    The kernel variance s^2 and length scale(s) l (and sigma_n^2 with the fitted nugget,
    and the quadratic mean's parameters, :mod:`bayescalib.inference.gp.mean`) maximize
    the evidence log p(L | s^2, l) with GPy's L-BFGS-B (``optimizer="lbfgsb"``) or scaled
    conjugate gradients (``"scg"``), from ``restarts`` starting points: the
    first a fixed default (s^2 = mean((L - m)^2), l = 0.3), the others drawn
    log-uniformly around it from ``numpy.random.default_rng(seed)``. The best
    evidence wins. Failed forward runs (non-finite L) are excluded before
    training; their number is kept in ``n_excluded``, and the points of those with
    L = -inf in ``X_failed``: the sampler's log-likelihood
    (:meth:`~bayescalib.inference.gp.predictor.GPSurrogate.loglik`) is -inf where they
    mark the model infeasible (:mod:`bayescalib.inference.feasibility`). With a
    ``bound`` the targets are the warped values g (:mod:`bayescalib.inference.gp.warping`).

Nugget (``surrogate.nugget``)
    ``fixed`` (the paper's): sigma_n^2 = f_n (max(y) - min(y)), f_n = ``nugget_factor``
    = 1e-5, fixed (not optimized), for numerical stability. The range of the targets is
    set by the far points of a design, so a fixed relative nugget is a noise on every
    value that caps the accuracy near the mode (``docs/surrogate.md``).

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
    floor and 1e-2 var(y); a refit of
    :func:`~bayescalib.inference.gp.selection.fit_round` adds one start at the previous
    round's kernel hyperparameters and nugget. Should
    K + sigma_n^2 I not factorize in float64 at the optimum (a smooth kernel, dense
    points), sigma_n^2 is raised tenfold until it does (logged; the evidence is
    recomputed there, :func:`_factorizable_nugget`). The fitted value travels in the
    surrogate file (``nugget``; ``nugget_mode`` says which rule made it; files written
    before it was recorded read as ``fixed``; :mod:`bayescalib.inference.gp.store`).
"""

from __future__ import annotations

import logging
import math
import warnings

import numpy as np

from bayescalib.config import defaults
from bayescalib.inference.gp.inputs import frame_extent, warp_inputs
from bayescalib.inference.gp.kernels import KERNELS, kernel_matrix
from bayescalib.inference.gp.mean import (
    QUAD_CENTER_MARGIN,
    _prefit_quadratic,
    _quadratic_mapping_class,
    quadratic_mean,
)
from bayescalib.inference.gp.predictor import GPSurrogate
from bayescalib.inference.gp.warping import log_misfit

__all__ = ["fit_gp"]

log = logging.getLogger(__name__)

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
    is :func:`~bayescalib.inference.gp.selection.fit_from_config` (with
    :func:`~bayescalib.inference.gp.selection.surrogate_settings` from Python); this is
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
        floor (this module's docstring).
    mean
        ``"constant"``: the fixed constant mean of ``mean_offset_factor``;
        ``"quadratic"``: the misfit-shaped mean (:mod:`bayescalib.inference.gp.mean`),
        its centre, widths and phi0 fitted by the evidence jointly with the kernel,
        starting from a least-squares fit to the targets
        (:func:`~bayescalib.inference.gp.mean._prefit_quadratic`).
    ard
        Per-dimension length scales instead of one.
    warp
        With a ``bound`` (then required): True models the log-misfit
        g = log(1 + B - y) (:mod:`bayescalib.inference.gp.warping`; values above B from
        round-off count as g = 0), False L itself. Without a bound: unused.
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
        (:func:`~bayescalib.inference.gp.inputs.principal_frame`); None: the box-scaled
        inputs themselves.
    log_offset
        (d,) offsets of the log inputs
        (:func:`~bayescalib.inference.gp.inputs.log_input_offsets`; NaN: linear), applied
        before the box scaling (the bounds are mapped alike); None: all linear.
    warm_start
        (kernel variance, length scale(s) of shape (1,) or (d,)[, nugget]) of the first
        optimizer start (a warm start, e.g. the previous round's optimum,
        :func:`~bayescalib.inference.gp.selection.fit_round`; the nugget is used with
        ``nugget="fit"`` only, clipped to its bounds); None: the fixed default. The other
        starts are drawn as without it. With ``nugget="fit"`` the warm start comes on top
        of the ``restarts`` starts (the fixed default included); with a fixed nugget it
        replaces the fixed default.

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
        y = log_misfit(y, bound)
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
    # can end far below the default start's evidence (docs/surrogate.md)
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
