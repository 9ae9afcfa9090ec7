"""Named model parameters, their priors, and the parameter space of a study.

The calibration problem (paper Sec. 2.2) has model inputs x with a prior p(x)
and, optionally, uncertain conditions theta (e.g. the inflow rate) with a
density p(theta). Both are represented here as :class:`Parameter` objects; an
uncertain condition is a parameter flagged ``uncertain=True``. The SMC samples
the *extended* posterior p(x, theta | Y) of eq. (cond_bayes)/(uncertain_bayes),
and the marginal posterior q(x | Y) of eq. (uncertain_bayes) is obtained by
simply dropping the theta columns of the particles (``calibrated_mask``).

Priors (all in the parameter's own unit)
---------------------------------------
* ``Uniform(lo, hi)``
* ``Normal(mu, sigma)``
* ``LogNormal(mu, sigma)`` -- mu and sigma of log(x); mode exp(mu - sigma^2)
* ``ScaledBeta(a, b, lo, hi)`` -- Beta(a, b) mapped linearly onto [lo, hi]

Paper values: E ~ U(100, 800) Pa, nu ~ U(-0.8, 0.5); informed
E ~ LogNormal(5.86, 0.4) (mode ~ 300 Pa), nu ~ Beta(43/13, 22/13) on
[-0.8, 0.5] (mode 0.2); inflow V_in ~ Beta(2.6, 1.4) on [0, 110] mm^2/s
(mode 88).

Design box and truncation
-------------------------
Every parameter has a design box [lo, hi]: the Sobol design, the GP input
scaling and the SMC all live in it. For unbounded priors (normal, lognormal)
the box must be given explicitly. The prior used in inference is the prior
*truncated to the box and renormalized*:

    p_box(x) = p(x) / (F(hi) - F(lo))   for lo <= x <= hi,   -inf outside,

so that ``ParameterSpace.logprior`` is a proper density on the box (the SMC
log-evidence is then correct) and ``sample_prior`` draws from it by inverse
CDF sampling. For uniform/beta priors whose support equals the box the
truncation is the identity.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayescalib.config import defaults

__all__ = [
    "LogNormal",
    "Normal",
    "Parameter",
    "ParameterError",
    "ParameterSpace",
    "Prior",
    "ScaledBeta",
    "Uniform",
    "parameter_target",
    "prior_from_config",
]


class ParameterError(ValueError):
    """A parameter or prior definition is invalid; the message names the parameter."""


# ---------------------------------------------------------------------------
# Priors
# ---------------------------------------------------------------------------


class Prior:
    """A univariate prior density in user units.

    Subclasses define ``_freeze`` (the frozen scipy distribution, built on first
    use: reading a study needs no scipy.stats), ``mode``, ``support`` and
    ``d2logpdf`` (second derivative of the log density, used by the Laplace
    approximation).
    """

    kind: str = ""

    def __init__(self) -> None:
        self._frozen = None

    @property
    def _dist(self):
        if self._frozen is None:
            from scipy import stats

            self._frozen = self._freeze(stats)
        return self._frozen

    def _freeze(self, stats):  # pragma: no cover - overridden
        raise NotImplementedError

    # densities ---------------------------------------------------------
    def logpdf(self, x: np.ndarray | float) -> np.ndarray:
        """Log density at ``x`` (any shape); -inf outside the support."""
        x = np.asarray(x, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.asarray(self._dist.logpdf(x), dtype=float)
        return np.where(np.isnan(out), -np.inf, out)

    def cdf(self, x: np.ndarray | float) -> np.ndarray:
        return np.asarray(self._dist.cdf(np.asarray(x, dtype=float)), dtype=float)

    def ppf(self, u: np.ndarray | float) -> np.ndarray:
        """Quantile function (inverse CDF) at ``u`` in [0, 1]."""
        return np.asarray(self._dist.ppf(np.asarray(u, dtype=float)), dtype=float)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` independent draws (shape (n,)) by inverse-CDF sampling."""
        return self.ppf(rng.random(n))

    @property
    def mean(self) -> float:
        return float(self._dist.mean())

    @property
    def std(self) -> float:
        return float(self._dist.std())

    @property
    def mode(self) -> float:  # pragma: no cover - overridden
        raise NotImplementedError

    @property
    def support(self) -> tuple[float, float]:
        lo, hi = self._dist.support()
        return float(lo), float(hi)

    def d2logpdf(self, x: np.ndarray | float) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def to_config(self) -> dict[str, Any]:  # pragma: no cover - overridden
        raise NotImplementedError

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.to_config().items() if k != "type")
        return f"{type(self).__name__}({args})"


class Uniform(Prior):
    """Uniform density on [lo, hi]."""

    kind = "uniform"

    def __init__(self, lo: float, hi: float) -> None:
        super().__init__()
        self.lo, self.hi = float(lo), float(hi)
        if not (np.isfinite(self.lo) and np.isfinite(self.hi)) or self.lo >= self.hi:
            raise ValueError(f"uniform prior needs finite lo < hi, got lo={lo}, hi={hi}")

    def _freeze(self, stats):
        return stats.uniform(loc=self.lo, scale=self.hi - self.lo)

    # closed forms: the study's check of its parameters needs no scipy.stats
    def logpdf(self, x):
        x = np.asarray(x, dtype=float)
        inside = (x >= self.lo) & (x <= self.hi)
        return np.where(inside, -np.log(self.hi - self.lo), -np.inf)

    def cdf(self, x):
        x = np.asarray(x, dtype=float)
        return np.clip((x - self.lo) / (self.hi - self.lo), 0.0, 1.0)

    def ppf(self, u):
        u = np.asarray(u, dtype=float)
        q = self.lo + u * (self.hi - self.lo)
        return np.where((u >= 0) & (u <= 1), q, np.nan)

    @property
    def mode(self) -> float:
        """Any point of [lo, hi] is a mode; the midpoint is returned."""
        return 0.5 * (self.lo + self.hi)

    def d2logpdf(self, x):
        return np.zeros_like(np.asarray(x, dtype=float))

    def to_config(self):
        return {"type": "uniform", "lo": self.lo, "hi": self.hi}


class Normal(Prior):
    """Normal density N(mu, sigma^2)."""

    kind = "normal"

    def __init__(self, mu: float, sigma: float) -> None:
        super().__init__()
        self.mu, self.sigma = float(mu), float(sigma)
        if not np.isfinite(self.mu) or not (self.sigma > 0 and np.isfinite(self.sigma)):
            raise ValueError(f"normal prior needs finite mu and sigma > 0, got mu={mu}, sigma={sigma}")

    def _freeze(self, stats):
        return stats.norm(loc=self.mu, scale=self.sigma)

    @property
    def mode(self) -> float:
        return self.mu

    def d2logpdf(self, x):
        return np.full_like(np.asarray(x, dtype=float), -1.0 / self.sigma**2)

    def to_config(self):
        return {"type": "normal", "mu": self.mu, "sigma": self.sigma}


class LogNormal(Prior):
    """Log-normal density: log(x) ~ N(mu, sigma^2); mode exp(mu - sigma^2)."""

    kind = "lognormal"

    def __init__(self, mu: float, sigma: float) -> None:
        super().__init__()
        self.mu, self.sigma = float(mu), float(sigma)
        if not np.isfinite(self.mu) or not (self.sigma > 0 and np.isfinite(self.sigma)):
            raise ValueError(
                f"lognormal prior needs finite mu and sigma > 0, got mu={mu}, sigma={sigma}"
            )

    def _freeze(self, stats):
        return stats.lognorm(s=self.sigma, scale=np.exp(self.mu))

    @property
    def mode(self) -> float:
        return float(np.exp(self.mu - self.sigma**2))

    def d2logpdf(self, x):
        # log p = -log x - (log x - mu)^2 / (2 s^2) + const
        x = np.asarray(x, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.log(x) - self.mu
            out = (1.0 + (t - 1.0) / self.sigma**2) / x**2
        return np.where(x > 0, out, np.nan)

    def to_config(self):
        return {"type": "lognormal", "mu": self.mu, "sigma": self.sigma}


class ScaledBeta(Prior):
    """Beta(a, b) density mapped linearly onto [lo, hi]."""

    kind = "beta"

    def __init__(self, a: float, b: float, lo: float = 0.0, hi: float = 1.0) -> None:
        super().__init__()
        self.a, self.b, self.lo, self.hi = float(a), float(b), float(lo), float(hi)
        if not (self.a > 0 and self.b > 0 and np.isfinite(self.a) and np.isfinite(self.b)):
            raise ValueError(f"beta prior needs a > 0 and b > 0, got a={a}, b={b}")
        if not (np.isfinite(self.lo) and np.isfinite(self.hi)) or self.lo >= self.hi:
            raise ValueError(f"beta prior needs finite lo < hi, got lo={lo}, hi={hi}")

    def _freeze(self, stats):
        return stats.beta(self.a, self.b, loc=self.lo, scale=self.hi - self.lo)

    @property
    def mode(self) -> float:
        """(a-1)/(a+b-2) mapped to [lo, hi] for a, b > 1; an end point otherwise."""
        a, b = self.a, self.b
        if a > 1 and b > 1:
            t = (a - 1) / (a + b - 2)
        elif a <= 1 < b or (a < 1 and b == 1):
            t = 0.0
        elif b <= 1 < a or (b < 1 and a == 1):
            t = 1.0
        else:  # a, b <= 1: bimodal or flat -> midpoint
            t = 0.5
        return self.lo + t * (self.hi - self.lo)

    def d2logpdf(self, x):
        x = np.asarray(x, dtype=float)
        w = self.hi - self.lo
        t = (x - self.lo) / w
        with np.errstate(divide="ignore", invalid="ignore"):
            out = (-(self.a - 1) / t**2 - (self.b - 1) / (1 - t) ** 2) / w**2
        return np.where((t > 0) & (t < 1), out, np.nan)

    def to_config(self):
        return {"type": "beta", "a": self.a, "b": self.b, "lo": self.lo, "hi": self.hi}


# ---------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------


@dataclass
class Parameter:
    """One named parameter with prior, design box, and metadata.

    Parameters
    ----------
    name
        Identifier (used as key in summaries and files).
    unit
        Unit string of the user-facing value (e.g. ``"Pa"``, ``"-"``).
    prior
        The prior density in user units.
    lo, hi
        Design box; the prior is truncated to [lo, hi] (see module docstring).
    uncertain
        True for an uncertain condition theta (marginalized out of the posterior).
    target
        Dotted key of the forward-model configuration this parameter sets
        (e.g. ``"material.E"``); stored only.
    ground_truth
        Known true value (synthetic data), or None.

    Raises
    ------
    ParameterError
        lo >= hi, non-finite bounds, no prior mass in the box, or ground truth
        outside the box/prior support. The message names the parameter.
    """

    name: str
    unit: str
    prior: Prior
    lo: float
    hi: float
    uncertain: bool = False
    target: str | None = None
    ground_truth: float | None = None
    _log_mass: float = field(init=False, repr=False, default=0.0)
    _cdf_lo: float = field(init=False, repr=False, default=0.0)
    _cdf_hi: float = field(init=False, repr=False, default=1.0)

    def __post_init__(self) -> None:
        nm = self.name
        if not isinstance(nm, str) or not nm:
            raise ParameterError(f"parameter name must be a non-empty string, got {nm!r}")
        if not isinstance(self.prior, Prior):
            raise ParameterError(f"parameter '{nm}': prior must be a Prior, got {self.prior!r}")
        try:
            self.lo, self.hi = float(self.lo), float(self.hi)
        except (TypeError, ValueError):
            raise ParameterError(
                f"parameter '{nm}': bounds must be numbers, got [{self.lo!r}, {self.hi!r}]"
            ) from None
        if not (np.isfinite(self.lo) and np.isfinite(self.hi)):
            raise ParameterError(f"parameter '{nm}': bounds must be finite, got [{self.lo}, {self.hi}]")
        if self.lo >= self.hi:
            raise ParameterError(
                f"parameter '{nm}': lower bound {self.lo} must be below upper bound {self.hi}"
            )
        self._cdf_lo = float(self.prior.cdf(self.lo))
        self._cdf_hi = float(self.prior.cdf(self.hi))
        mass = self._cdf_hi - self._cdf_lo
        if not mass > 0:
            raise ParameterError(
                f"parameter '{nm}': the prior {self.prior!r} has no mass in the box "
                f"[{self.lo}, {self.hi}]"
            )
        self._log_mass = float(np.log(mass))
        if self.ground_truth is not None:
            gt = float(self.ground_truth)
            if not (self.lo <= gt <= self.hi) or not np.isfinite(self.prior.logpdf(gt)):
                raise ParameterError(
                    f"parameter '{nm}': ground truth {gt} is outside the support "
                    f"(box [{self.lo}, {self.hi}], prior {self.prior!r})"
                )
            self.ground_truth = gt
        self.uncertain = bool(self.uncertain)

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Log density of the box-truncated prior; -inf outside [lo, hi]."""
        x = np.asarray(x, dtype=float)
        inside = (x >= self.lo) & (x <= self.hi)
        lp = self.prior.logpdf(np.clip(x, self.lo, self.hi)) - self._log_mass
        return np.where(inside, lp, -np.inf)

    def ppf(self, u: np.ndarray) -> np.ndarray:
        """Quantile function of the box-truncated prior."""
        u = np.asarray(u, dtype=float)
        q = self.prior.ppf(self._cdf_lo + u * (self._cdf_hi - self._cdf_lo))
        return np.clip(q, self.lo, self.hi)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws from the box-truncated prior (inverse-CDF sampling)."""
        return self.ppf(rng.random(n))

    def to_config(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "unit": self.unit,
            "prior": self.prior.to_config(),
            "bounds": [self.lo, self.hi],
            "uncertain": self.uncertain,
            "target": self.target,
            "ground_truth": self.ground_truth,
        }


def prior_from_config(
    entry: Mapping[str, Any], bounds: Sequence[float] | None, name: str
) -> Prior:
    """Build a :class:`Prior` from ``{type: ..., ...}``; uniform/beta lo, hi default to ``bounds``."""
    if not isinstance(entry, Mapping) or "type" not in entry:
        raise ParameterError(f"parameter '{name}': prior must be a mapping with a 'type' key")
    kind = str(entry["type"]).lower()
    known = {"uniform", "normal", "lognormal", "beta"}
    allowed_keys = {
        "uniform": {"type", "lo", "hi"},
        "normal": {"type", "mu", "sigma"},
        "lognormal": {"type", "mu", "sigma"},
        "beta": {"type", "a", "b", "lo", "hi"},
    }
    if kind not in known:
        raise ParameterError(
            f"parameter '{name}': unknown prior type {entry['type']!r}; "
            f"known: {', '.join(sorted(known))}"
        )
    extra = set(entry) - allowed_keys[kind]
    if extra:
        raise ParameterError(
            f"parameter '{name}': unknown key(s) {sorted(extra)} for a {kind} prior; "
            f"allowed: {sorted(allowed_keys[kind])}"
        )

    def get(key: str, default: Any = None) -> float:
        val = entry.get(key, default)
        if val is None:
            raise ParameterError(f"parameter '{name}': {kind} prior needs '{key}'")
        try:
            return float(val)
        except (TypeError, ValueError):
            raise ParameterError(f"parameter '{name}': prior '{key}' must be a number, got {val!r}") from None

    blo = bounds[0] if bounds is not None else None
    bhi = bounds[1] if bounds is not None else None
    try:
        if kind == "uniform":
            return Uniform(get("lo", blo), get("hi", bhi))
        if kind == "normal":
            return Normal(get("mu"), get("sigma"))
        if kind == "lognormal":
            return LogNormal(get("mu"), get("sigma"))
        return ScaledBeta(get("a"), get("b"), get("lo", blo), get("hi", bhi))
    except ParameterError:
        raise
    except ValueError as exc:
        raise ParameterError(f"parameter '{name}': {exc}") from None


# ---------------------------------------------------------------------------
# Parameter space
# ---------------------------------------------------------------------------


class ParameterSpace:
    """An ordered set of parameters: the columns of every particle/design array.

    The prior is the product of the (box-truncated) univariate priors.
    """

    def __init__(self, parameters: Iterable[Parameter]) -> None:
        self.parameters: list[Parameter] = list(parameters)
        if not self.parameters:
            raise ParameterError("a parameter space needs at least one parameter")
        seen: set[str] = set()
        for p in self.parameters:
            if p.name in seen:
                raise ParameterError(f"parameter '{p.name}' is defined twice")
            seen.add(p.name)

    # descriptive -------------------------------------------------------
    @property
    def names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def units(self) -> list[str]:
        return [p.unit for p in self.parameters]

    @property
    def targets(self) -> list[str | None]:
        return [p.target for p in self.parameters]

    @property
    def dim(self) -> int:
        return len(self.parameters)

    @property
    def bounds(self) -> np.ndarray:
        """Design box, shape (d, 2): column 0 lower, column 1 upper bounds."""
        return np.array([[p.lo, p.hi] for p in self.parameters], dtype=float)

    @property
    def calibrated_mask(self) -> np.ndarray:
        """Boolean (d,): True for calibrated inputs x, False for uncertain conditions theta."""
        return np.array([not p.uncertain for p in self.parameters], dtype=bool)

    @property
    def calibrated_names(self) -> list[str]:
        return [p.name for p in self.parameters if not p.uncertain]

    @property
    def ground_truth(self) -> np.ndarray | None:
        """(d,) array of ground-truth values, or None unless every parameter has one."""
        gts = [p.ground_truth for p in self.parameters]
        if any(g is None for g in gts):
            return None
        return np.array(gts, dtype=float)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ParameterError(f"unknown parameter '{name}'; known: {', '.join(self.names)}") from None

    # densities ---------------------------------------------------------
    def _as_2d(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        if X.ndim == 1:
            X = X[None, :]
        if X.ndim != 2 or X.shape[1] != self.dim:
            raise ValueError(f"expected an array of shape (N, {self.dim}), got {X.shape}")
        return X

    def logprior(self, X: np.ndarray) -> np.ndarray:
        """Log prior density (box-truncated, normalized on the box), shape (N,).

        -inf for rows outside the box; never NaN (NaN inputs give -inf).
        """
        X = self._as_2d(X)
        out = np.zeros(X.shape[0])
        for j, p in enumerate(self.parameters):
            out += p.logpdf(X[:, j])
        return np.where(np.isnan(out), -np.inf, out)

    def sample_prior(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` independent draws from the truncated prior, shape (n, d)."""
        U = rng.random((n, self.dim))
        return np.column_stack([p.ppf(U[:, j]) for j, p in enumerate(self.parameters)])

    def d2logprior(self, x: np.ndarray) -> np.ndarray:
        """Diagonal of the Hessian of the log prior at one point ``x`` (d,)."""
        x = np.asarray(x, dtype=float)
        return np.array([float(p.prior.d2logpdf(x[j])) for j, p in enumerate(self.parameters)])

    def prior_mean(self) -> np.ndarray:
        """Mean of the untruncated priors, (d,)."""
        return np.array([p.prior.mean for p in self.parameters])

    def prior_mode(self) -> np.ndarray:
        """Mode of the untruncated priors clipped to the box, (d,)."""
        return np.array([np.clip(p.prior.mode, p.lo, p.hi) for p in self.parameters])

    # scaling -------------------------------------------------------------
    def to_unit(self, X: np.ndarray) -> np.ndarray:
        """Map user units to the unit box [0, 1]^d."""
        b = self.bounds
        return (np.asarray(X, dtype=float) - b[:, 0]) / (b[:, 1] - b[:, 0])

    def from_unit(self, U: np.ndarray) -> np.ndarray:
        """Map the unit box [0, 1]^d to user units."""
        b = self.bounds
        return b[:, 0] + np.asarray(U, dtype=float) * (b[:, 1] - b[:, 0])

    # config ----------------------------------------------------------------
    @classmethod
    def from_config(cls, entries: Sequence[Mapping[str, Any]]) -> ParameterSpace:
        """Build a space from the ``parameters`` config section (a list of mappings).

        Each entry: ``name``, ``unit``, ``prior`` ``{type, ...}``,
        ``bounds`` [lo, hi] (optional for uniform/beta priors: defaults to the
        prior's lo/hi), ``uncertain``, ``target`` (:func:`parameter_target`),
        ``ground_truth``; a key left out takes the schema's default
        (``inference.schema.yaml``, ``definitions/parameter``).
        """
        if not isinstance(entries, Sequence) or isinstance(entries, (str, bytes)):
            raise ParameterError("parameters must be a list of parameter entries")
        params = []
        allowed = {"name", "unit", "prior", "bounds", "uncertain", "target", "ground_truth"}
        for i, e in enumerate(entries):
            if not isinstance(e, Mapping) or "name" not in e:
                raise ParameterError(f"parameter entry [{i}] must be a mapping with a 'name'")
            name = str(e["name"])
            extra = set(e) - allowed
            if extra:
                raise ParameterError(
                    f"parameter '{name}': unknown key(s) {sorted(extra)}; allowed: {sorted(allowed)}"
                )
            if "prior" not in e:
                raise ParameterError(f"parameter '{name}': missing 'prior'")
            bounds = e.get("bounds")
            if bounds is not None and (not isinstance(bounds, Sequence) or len(bounds) != 2):
                raise ParameterError(f"parameter '{name}': bounds must be [lo, hi], got {bounds!r}")
            prior = prior_from_config(e["prior"], bounds, name)
            if bounds is None:
                if isinstance(prior, (Uniform, ScaledBeta)):
                    bounds = [prior.lo, prior.hi]
                else:
                    raise ParameterError(
                        f"parameter '{name}': a {prior.kind} prior is unbounded, so 'bounds' "
                        f"[lo, hi] must be given (the prior is truncated to them)"
                    )
            e = {**defaults("inference", "parameter"), **e}  # a plain mapping: the schema's
            params.append(
                Parameter(
                    name=name,
                    unit=str(e["unit"]),
                    prior=prior,
                    lo=bounds[0],
                    hi=bounds[1],
                    uncertain=bool(e["uncertain"]),
                    target=parameter_target(e),
                    ground_truth=e["ground_truth"],
                )
            )
        return cls(params)

    def to_config(self) -> list[dict[str, Any]]:
        return [p.to_config() for p in self.parameters]

    def __repr__(self) -> str:
        return f"ParameterSpace({', '.join(self.names)})"


def parameter_target(entry: Mapping[str, Any]) -> str:
    """The forward-model key that a ``parameters`` entry sets: its ``target``, or its
    ``name`` where it has none (``target: null``, the schema's default). The study fills
    every entry's ``target`` with it once, when it reads its config
    (:class:`bayescalib.study.Study`); the rest of the code reads ``p["target"]``."""
    return str(entry.get("target") or entry["name"])
