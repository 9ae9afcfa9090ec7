"""Posterior summaries of the SMC particle approximation (paper Sec. 2.2, 4.3-4.4).

All summaries are weighted sums over the final particles (eq. smcintegration).

* **Marginalizing uncertain conditions.** The SMC samples the extended
  posterior p(x, theta | Y) (eq. cond_bayes, eq. uncertain_bayes); the marginal
  q(x | Y) is represented by the same particles with the theta columns dropped.
  Every x-only summary below (``map``, ``map_marginal``, ``gaussian``,
  ``laplace``) is therefore a summary of q(x | Y).
* **Mean and covariance** with weights W (covariance with the reliability-
  weights correction 1 / (1 - sum W^2)).
* **Credible intervals**: equal-tailed, from weighted quantiles
  ((1 - l)/2, (1 + l)/2) for every level l.
* **MAP**: the particle of the last step with the highest unnormalized log
  posterior log L + log p, reported without the uncertain parameters.
* **MAP after marginalizing theta**: the centre of the fullest bin of the
  weighted histogram of the calibrated columns over their design box (30 bins
  per input for up to 2 calibrated inputs, 10 otherwise -- the paper's choice;
  configurable).
* **Global Gaussian approximation**: N(mean, cov) of q(x | Y).
* **A posterior cut by its box** (:func:`against_bounds`): a parameter whose
  marginal density at an end of its design box is still at least
  :data:`EDGE_DENSITY` of its peak, while the posterior is concentrated (sd below
  :data:`INFORMED_SD` of the box): the data favour values beyond the box, which the
  prior (or the box) excludes. The density at the end is the mass of the strip of half
  an sd (at most 2 % of the box) there against the fullest such strip, so a truncated
  Gaussian is flagged when its centre lies within about 2.4 sd of the end. A posterior spread over
  most of its box (a weakly informed parameter, e.g. nu) is not: there the prior
  decides every end, as expected. Nor is an end that is the model's own limit (the
  fsi model's range of the target, e.g. nu <= 0.5, ``bayescalib.config.schema_limits``):
  no prior can widen it.
* **Laplace approximation** at the MAP: covariance (-H)^{-1}, H the Hessian of
  log L + log p in all inputs, log L by central finite differences on the
  surrogate (step ``fd_step`` times the box width per input), log p
  analytically (the priors' second derivatives; the box truncation only adds a
  constant). The calibrated block of (-H)^{-1} is the Laplace covariance of
  q(x | Y). If -H is not positive definite (e.g. the MAP sits on a flat ridge
  or at the box edge), the result says so (``positive_definite: false``,
  ``cov: null``) and lists the eigenvalues of -H.

Storage: particles, weights, log-likelihood, log prior and the SMC history go
to HDF5; equally weighted draws (systematic resampling of the final particles)
go to a NetCDF file written by ArviZ (InferenceData): group ``posterior`` with
one variable per parameter, dims (chain, draw), and group ``sample_stats`` with
``lp`` (log posterior), ``surrogate_loglik``, ``log_weight`` (normalized log
weight of the particle the draw was copied from) and ``particle_index``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.inference.parameters import ParameterSpace
from bayescalib.inference.resampling import systematic_resample
from bayescalib.inference.smc import SMCResult, weighted_cov
from bayescalib.inference.weights import ess, weighted_quantile
from bayescalib.io._atomic_write import atomic_path
from bayescalib.io.header import validate_header, write_header

__all__ = [
    "against_bounds",
    "credible_intervals",
    "equal_weight_draws",
    "laplace_approximation",
    "map_estimate",
    "map_marginal",
    "read_particles_h5",
    "summarize",
    "weighted_mean_cov",
    "write_netcdf",
    "write_particles_h5",
]


def weighted_mean_cov(X: np.ndarray, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (d,) and covariance (d, d) of particles X (N, d), weights W (N,)."""
    W = np.asarray(W, float) / np.sum(W)
    return W @ X, weighted_cov(np.asarray(X, float), W)


def credible_intervals(
    X: np.ndarray, W: np.ndarray, levels: Sequence[float]
) -> np.ndarray:
    """Equal-tailed intervals, shape (len(levels), d, 2)."""
    out = np.empty((len(levels), X.shape[1], 2))
    for k, lv in enumerate(levels):
        q = np.array([(1.0 - lv) / 2.0, (1.0 + lv) / 2.0])
        for j in range(X.shape[1]):
            out[k, j] = weighted_quantile(X[:, j], W, q)
    return out


def map_estimate(result: SMCResult) -> tuple[np.ndarray, float]:
    """Best particle (d,) by log L + log p, and its log posterior."""
    lpost = result.log_posterior
    i = int(np.argmax(lpost))
    return result.particles[i].copy(), float(lpost[i])


def map_marginal(
    X: np.ndarray, W: np.ndarray, bounds: np.ndarray, bins: int
) -> np.ndarray:
    """Centre of the fullest cell of the weighted histogram of X (N, k) over ``bounds`` (k, 2)."""
    H, edges = np.histogramdd(X, bins=bins, range=[tuple(b) for b in bounds], weights=W)
    idx = np.unravel_index(int(np.argmax(H)), H.shape)
    return np.array([0.5 * (e[i] + e[i + 1]) for e, i in zip(edges, idx)])


def _fd_hessian(
    f: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, h: np.ndarray
) -> np.ndarray:
    """Central finite-difference Hessian of a vectorized scalar function at x0, one batch call."""
    d = x0.size
    pts = [x0]
    for i in range(d):
        e = np.zeros(d)
        e[i] = h[i]
        pts += [x0 + e, x0 - e]
    pairs = [(i, j) for i in range(d) for j in range(i + 1, d)]
    for i, j in pairs:
        ei = np.zeros(d)
        ej = np.zeros(d)
        ei[i] = h[i]
        ej[j] = h[j]
        pts += [x0 + ei + ej, x0 + ei - ej, x0 - ei + ej, x0 - ei - ej]
    v = np.asarray(f(np.array(pts)), float)
    f0 = v[0]
    H = np.empty((d, d))
    for i in range(d):
        H[i, i] = (v[1 + 2 * i] - 2 * f0 + v[2 + 2 * i]) / h[i] ** 2
    base = 1 + 2 * d
    for k, (i, j) in enumerate(pairs):
        pp, pm, mp, mm = v[base + 4 * k : base + 4 * k + 4]
        H[i, j] = H[j, i] = (pp - pm - mp + mm) / (4 * h[i] * h[j])
    return H


def laplace_approximation(
    loglik: Callable[[np.ndarray], np.ndarray],
    space: ParameterSpace,
    x_map: np.ndarray,
    *,
    fd_step: float = 1e-3,
) -> dict[str, Any]:
    """Laplace approximation of q(x | Y) at the MAP (all inputs, then the calibrated block).

    Returns
    -------
    dict with ``names`` (calibrated), ``mean`` (MAP, calibrated), ``cov``
    ((k, k) list or None), ``positive_definite``, ``eigenvalues`` (of -H, all
    inputs), ``hessian`` (H, all inputs), ``fd_step``.
    """
    b = space.bounds
    h = fd_step * (b[:, 1] - b[:, 0])
    x_map = np.asarray(x_map, float)
    H = _fd_hessian(loglik, x_map, h) + np.diag(space.d2logprior(x_map))
    mask = space.calibrated_mask
    out: dict[str, Any] = {
        "names": space.calibrated_names,
        "mean": x_map[mask].tolist(),
        "fd_step": fd_step,
        "hessian": H.tolist() if np.all(np.isfinite(H)) else None,
        "hessian_convention": "hessian: second derivatives of the log posterior density at "
                              "the MAP (all inputs, central finite differences; negative "
                              "definite at a maximum); cov = inverse of -hessian, calibrated "
                              "block",
    }
    if not np.all(np.isfinite(H)):
        out.update(positive_definite=False, cov=None, eigenvalues=None,
                   note="non-finite Hessian (MAP at the edge of the likelihood/prior support)")
        return out
    negH = -0.5 * (H + H.T)
    eig = np.linalg.eigvalsh(negH)
    out["eigenvalues"] = eig.tolist()
    if eig.min() <= 0:
        out.update(positive_definite=False, cov=None,
                   note="-Hessian is not positive definite; no Laplace covariance")
        return out
    C = np.linalg.inv(negH)
    out.update(positive_definite=True, cov=C[np.ix_(mask, mask)].tolist())
    return out


#: the marginal density at a box end, relative to its peak, from which the posterior
#: counts as cut by the box (a truncated Gaussian centred 2.4 sd inside)
EDGE_DENSITY = 0.1
#: the posterior sd, relative to the box width, below which a parameter counts as
#: informed by the data (a uniform posterior has 0.29)
INFORMED_SD = 0.2
#: least posterior mass in the strip at the end for a flag (a few particles are noise)
EDGE_MASS = 0.01


def against_bounds(X: np.ndarray, W: np.ndarray, space: ParameterSpace) -> list[dict[str, Any]]:
    """The parameters whose posterior is cut by an end of their design box.

    The marginal density at each end is estimated by the weighted mass of the strip
    ``[end, end + delta]`` (``delta`` the smaller of 2 % of the box width and half the
    posterior sd) against the fullest strip of that width over the box (module
    docstring, :data:`EDGE_DENSITY`, :data:`INFORMED_SD`, :data:`EDGE_MASS`).

    Parameters
    ----------
    X : ndarray, shape (N, d)
        Particles, user units (every parameter of ``space``, uncertain ones included).
    W : ndarray, shape (N,)
        Weights (normalised here).
    space : ParameterSpace
        The parameters; ``space.bounds`` is the box the SMC sampled, ``space.targets``
        name the model keys whose own limits are no prior's.

    Returns
    -------
    list of dict
        One per cut end: ``name``, ``index`` (in ``space.names``), ``side`` ("lower" or
        "upper"), ``bound`` (user units), ``density_ratio`` (at the end over the peak),
        ``edge_mass`` (posterior mass within ``delta`` of the end), ``delta``,
        ``sd_fraction`` (posterior sd over the box width).
    """
    from bayescalib.config import schema_limits

    X = np.asarray(X, float)
    W = np.asarray(W, float) / np.sum(W)
    out: list[dict[str, Any]] = []
    for j, name in enumerate(space.names):
        lo, hi = (float(v) for v in space.bounds[j])
        width = hi - lo
        target = space.targets[j]
        limits = schema_limits("fsi", target) if target else (None, None)
        x = X[:, j]
        mu = float(W @ x)
        sd = float(np.sqrt(max(W @ (x - mu) ** 2, 0.0)))
        if not width > 0 or sd >= INFORMED_SD * width:
            continue
        delta = min(0.02 * width, 0.5 * sd) if sd > 0 else 0.02 * width
        n = int(np.ceil(width / delta))
        mass, _ = np.histogram(x, bins=n, range=(lo, lo + n * delta), weights=W)
        peak = float(mass.max())
        ends = (("lower", lo, float(W[x <= lo + delta].sum())),
                ("upper", hi, float(W[x >= hi - delta].sum())))
        for (side, bound, edge), limit in zip(ends, limits, strict=True):
            if limit is not None and abs(bound - limit) <= 1e-9 * width:
                continue  # the model's own limit: no prior widens it
            ratio = edge / peak if peak > 0 else 0.0
            if ratio >= EDGE_DENSITY and edge >= EDGE_MASS:
                out.append({"name": name, "index": j, "side": side, "bound": bound,
                            "density_ratio": min(ratio, 1.0), "edge_mass": edge,
                            "delta": delta, "sd_fraction": sd / width})
    return out


def _default_bins(n_calibrated: int) -> int:
    return 30 if n_calibrated <= 2 else 10


def summarize(
    result: SMCResult,
    space: ParameterSpace,
    *,
    loglik: Callable[[np.ndarray], np.ndarray] | None = None,
    map_bins: int | None = None,
    levels: Sequence[float] = (0.5, 0.9, 0.99),
    fd_step: float = 1e-3,
) -> dict[str, Any]:
    """JSON-serializable posterior summary (user units, ordered/keyed by parameter name).

    Parameters
    ----------
    result
        Final SMC particles.
    space
        The parameter space the SMC ran on.
    loglik
        The log-likelihood the SMC used (the surrogate); needed for the Laplace
        approximation (``laplace`` is None without it).
    map_bins
        Bins per calibrated input for ``map_marginal``; None = 30 (<= 2
        calibrated inputs) or 10.
    levels
        Credible levels of the equal-tailed intervals.
    fd_step
        Finite-difference step of the Laplace Hessian, as a fraction of the box width.

    Returns
    -------
    dict with keys ``names``, ``units``, ``calibrated``, ``uncertain``,
    ``mean``/``std`` ({name: value}), ``cov`` (list of lists in ``names``
    order), ``intervals`` ({name: {str(level): [lo, hi]}}), ``map``
    ({calibrated name: value}), ``map_full`` (all names), ``map_log_posterior``,
    ``map_marginal`` ({calibrated name: value}), ``map_bins``, ``gaussian``
    ({names, mean, cov} of the calibrated inputs), ``laplace``, ``against_bounds``
    (:func:`against_bounds`), ``log_evidence``, ``ess``, ``n_particles``, ``n_steps``, ``ground_truth``.
    """
    X = np.asarray(result.particles, float)
    W = np.asarray(result.weights, float)
    W = W / W.sum()
    names = space.names
    mask = space.calibrated_mask
    cal = space.calibrated_names
    mean, cov = weighted_mean_cov(X, W)
    ci = credible_intervals(X, W, levels)
    x_map, lp_map = map_estimate(result)
    bins = _default_bins(int(mask.sum())) if map_bins is None else int(map_bins)
    x_mm = map_marginal(X[:, mask], W, space.bounds[mask], bins)
    summary: dict[str, Any] = {
        "names": names,
        "units": space.units,
        "calibrated": cal,
        "uncertain": [n for n, m in zip(names, mask) if not m],
        "mean": dict(zip(names, mean.tolist())),
        "std": dict(zip(names, np.sqrt(np.diag(cov)).tolist())),
        "cov": cov.tolist(),
        "intervals": {
            n: {str(lv): ci[k, j].tolist() for k, lv in enumerate(levels)}
            for j, n in enumerate(names)
        },
        "map": {n: float(v) for n, v in zip(cal, x_map[mask])},
        "map_full": dict(zip(names, x_map.tolist())),
        "map_log_posterior": lp_map,
        "map_marginal": dict(zip(cal, x_mm.tolist())),
        "map_bins": bins,
        "gaussian": {
            "names": cal,
            "mean": mean[mask].tolist(),
            "cov": cov[np.ix_(mask, mask)].tolist(),
        },
        "laplace": None,
        "against_bounds": against_bounds(X, W, space),
        "log_evidence": float(result.log_evidence),
        "ess": ess(W),
        "n_particles": int(X.shape[0]),
        "n_steps": int(result.n_steps),
        "ground_truth": None
        if space.ground_truth is None
        else dict(zip(names, space.ground_truth.tolist())),
    }
    if loglik is not None:
        summary["laplace"] = laplace_approximation(loglik, space, x_map, fd_step=fd_step)
    return summary


# ---------------------------------------------------------------------------
# storage
# ---------------------------------------------------------------------------


def write_particles_h5(path: str | Path, result: SMCResult, space: ParameterSpace) -> None:
    """Write particles, weights, log L, log prior, log posterior and the history (atomic)."""
    import h5py

    with atomic_path(path, suffix=".h5") as tmp, h5py.File(tmp, "w") as f:
        write_header(f, "particles")
        f.attrs["names"] = np.array(space.names, dtype=h5py.string_dtype())
        f.attrs["units"] = np.array(space.units, dtype=h5py.string_dtype())
        f.attrs["uncertain"] = ~space.calibrated_mask
        f.attrs["log_evidence"] = float(result.log_evidence)
        f.attrs["n_steps"] = int(result.n_steps)
        f.attrs["n_loglik_evals"] = int(result.n_loglik_evals)
        f.create_dataset("particles", data=result.particles)
        f.create_dataset("weights", data=result.weights)
        f.create_dataset("loglik", data=result.loglik)
        f.create_dataset("logprior", data=result.logprior)
        f.create_dataset("log_posterior", data=result.log_posterior)
        g = f.create_group("history")
        for k, v in result.history.items():
            g.create_dataset(k, data=np.asarray(v))


def read_particles_h5(path: str | Path) -> SMCResult:
    """Read a file written by :func:`write_particles_h5` back into an :class:`SMCResult`."""
    import h5py

    with h5py.File(path, "r") as f:
        validate_header(f, "particles", path)
        names = [n.decode() if isinstance(n, bytes) else str(n) for n in f.attrs["names"]]
        return SMCResult(
            particles=f["particles"][()],
            weights=f["weights"][()],
            loglik=f["loglik"][()],
            logprior=f["logprior"][()],
            log_evidence=float(f.attrs["log_evidence"]),
            history={k: f["history"][k][()] for k in f["history"]},
            n_steps=int(f.attrs["n_steps"]),
            n_loglik_evals=int(f.attrs["n_loglik_evals"]),
            names=names,
        )


def equal_weight_draws(result: SMCResult, n: int, seed: int) -> np.ndarray:
    """``n`` equally weighted posterior draws, shape (n, d): a systematic resample of the
    final SMC particles ``result`` (as :func:`read_particles_h5` reads them), with a
    generator seeded by ``seed`` (the same draws in every job)."""
    from bayescalib.inference.resampling import systematic_resample

    idx = systematic_resample(np.asarray(result.weights), np.random.default_rng(seed), n)
    return np.asarray(result.particles)[idx]


def write_netcdf(
    path: str | Path,
    result: SMCResult,
    space: ParameterSpace,
    rng: np.random.Generator,
    n_draws: int,
) -> np.ndarray:
    """Export ``n_draws`` equally weighted draws as an ArviZ ``InferenceData`` NetCDF.

    Draws are a systematic resample of the final particles (randomly permuted), one
    chain. Groups (written by ArviZ): ``posterior`` (one (chain=1, draw) variable per
    parameter, with ``units`` and ``uncertain`` attributes) and ``sample_stats``
    (``lp``, ``surrogate_loglik``: the GP surrogate's log-likelihood, ``log_weight``,
    ``particle_index``). Written
    atomically; ``arviz.from_netcdf`` reads it back.

    Returns
    -------
    (n_draws,) indices of the particles that were drawn.
    """
    az = _arviz()
    W = np.asarray(result.weights, float)
    W = W / W.sum()
    idx = systematic_resample(W, rng, n_draws)
    idx = idx[rng.permutation(n_draws)]
    with np.errstate(divide="ignore"):
        logw = np.log(W[idx])
    post = {name: np.asarray(result.particles)[idx, j][None, :]
            for j, name in enumerate(space.names)}
    stats = {"lp": np.asarray(result.log_posterior)[idx][None, :],
             "surrogate_loglik": np.asarray(result.loglik)[idx][None, :],
             "log_weight": logw[None, :], "particle_index": idx.astype(np.int64)[None, :]}
    idata = az.from_dict(posterior=post, sample_stats=stats,
                         attrs={"inference_library": "bayescalib",
                                "sampler": "SMC with adaptive tempering on a GP surrogate"})
    for j, (name, unit) in enumerate(zip(space.names, space.units, strict=True)):
        idata.posterior[name].attrs.update(units=unit,
                                           uncertain=int(not space.calibrated_mask[j]))
    with atomic_path(path, suffix=".nc") as tmp:
        idata.to_netcdf(str(tmp))
    return idx


def _arviz():
    """ArviZ, imported without its notice about a future refactor (this module pins a
    version whose API it uses)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz

    return arviz
