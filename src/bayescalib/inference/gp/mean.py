"""The GP's prior mean: the constant and the misfit-shaped (quadratic) mean.

Constant prior mean (App. D remark; ``mean="constant"``)
    m = min(L) - f_m (max(L) - min(L)),   f_m = ``mean_offset_factor`` = 1.0,
    so far from the data the surrogate log-likelihood falls below every observed
    value (the likelihood tends to zero rather than to exp(0)). For the log-misfit GP
    the same rule places m above every warped value
    (:mod:`bayescalib.inference.gp.warping`). The constant is set by
    :func:`~bayescalib.inference.gp.fit.fit_gp` and not optimized.

Misfit-shaped prior mean (``mean="quadratic"``; ``surrogate.mean``)
    With the constant mean the surrogate reverts to a floor away from the solves, so
    the SMC posterior sits where the best solves are and an active design crawls up a
    likelihood's slope a few posterior sd per round (``docs/surrogate.md``). A Gaussian
    log-likelihood of a smooth forward model is close to quadratic near its mode
    (L = B - Phi, Phi ~ phi0 + 1/2 (x - x0)^T H (x - x0) by Gauss-Newton), so the mean
    is given that shape:

        Phi_m(u) = phi0 + 1/2 | R (u - c) |^2,   R upper triangular, R^T R = H in u,

    in the GP's input frame u (log inputs, box scaling and principal frame included,
    :mod:`bayescalib.inference.gp.inputs`), carried through the output transform:
    m(u) = log(1 + Phi_m(u)) for the log-misfit GP (the quadratic misfit, warped as the
    targets are), m(u) = top - Phi_m(u) for a GP of L, top = B (so the mean never
    exceeds the bound) or max(L) + range(L) without one. This is VBMC's
    negative-quadratic mean function (Acerbi 2018, 2020:
    m(x) = m0 - 1/2 sum_i ((x_i - x0_i) / w_i)^2, fitted with the kernel) with two
    changes: a full Cholesky factor instead of per-axis widths, because the posteriors
    here have ridges (E_i along the inflow rate) that a diagonal quadratic in a
    misplaced frame cannot follow (on ``sloppy4d`` the diagonal version mispredicted
    the next batch by orders of magnitude more than the full one; ``docs/surrogate.md``),
    and the mean built on the misfit, so that it lives in the log-misfit warping the
    pipeline uses. c, R and phi0 are hyperparameters maximized with the kernel's by the
    evidence (GPy, analytic gradients through a custom mapping,
    :func:`_quadratic_mapping_class`), each start from a bounded least-squares fit of
    the mean to the targets (:func:`_prefit_quadratic`). Bounds: c within the box's
    image in the frame (:func:`~bayescalib.inference.gp.inputs.frame_extent`) widened by
    half its extent on each side; the diagonal widths 1 / R_jj between 1e-4 and 1e2
    extents; phi0 >= 0. Far from the solves the surrogate then keeps climbing toward the
    fitted mode (and falls off quadratically beyond it) instead of reverting to a floor.
"""

from __future__ import annotations

from functools import cache

import numpy as np

__all__ = ["QUAD_CENTER_MARGIN", "QUAD_WIDTH_SHARE", "quadratic_mean", "quadratic_misfit"]

#: smallest and largest width 1 / R_jj of the quadratic mean along input j, as shares of
#: the input frame's extent (a width of the whole extent changes the misfit by 1/2 nat
#: across the box: a direction the likelihood hardly sees)
QUAD_WIDTH_SHARE = (1e-4, 1e2)
#: how far outside the box (in the GP's input frame) the quadratic's centre may lie, as a
#: share of the box's extent on each side
QUAD_CENTER_MARGIN = 0.5


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
