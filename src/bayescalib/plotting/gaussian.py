"""Geometry of Gaussian approximations: probability ellipses in 2-D.

For a 2-D Gaussian N(m, C) the region holding probability p is the ellipse
``(x - m)^T C^{-1} (x - m) <= r^2`` with ``r^2 = -2 ln(1 - p)`` (the chi-square
quantile with 2 degrees of freedom). Its semi-axes are ``r * sqrt(lambda_k)``
along the eigenvectors of C.
"""

from __future__ import annotations

import numpy as np

from ._validation import as_array

__all__ = ["chi2_radius2", "ellipse_axes", "ellipse_points", "mass_outside_box"]


def chi2_radius2(p: float) -> float:
    """Squared Mahalanobis radius of the p-mass ellipse of a 2-D Gaussian.

    Parameters
    ----------
    p : float in (0, 1)
        Probability mass.

    Returns
    -------
    float
        ``-2 ln(1 - p)``.
    """
    if not 0.0 < p < 1.0:
        raise ValueError(f"probability level must lie in (0, 1), got {p}")
    return float(-2.0 * np.log1p(-p))


def _validate_cov(cov) -> np.ndarray:
    c = as_array(cov, "cov", shape=(2, 2))
    if not np.allclose(c, c.T, rtol=1e-8, atol=1e-12 * np.abs(c).max()):
        raise ValueError("cov: covariance matrix must be symmetric")
    if np.any(np.linalg.eigvalsh(c) <= 0):
        raise ValueError("cov: covariance matrix must be positive definite")
    return 0.5 * (c + c.T)


def ellipse_axes(cov, p: float) -> tuple[np.ndarray, float]:
    """Semi-axes and orientation of the p-mass ellipse.

    Parameters
    ----------
    cov : array_like, shape (2, 2)
        Covariance in user units squared.
    p : float
        Probability mass.

    Returns
    -------
    semi_axes : numpy.ndarray, shape (2,)
        Major, minor semi-axis (user units; meaningful as lengths only when
        both parameters share a unit).
    angle : float
        Angle of the major axis to the first coordinate axis [rad], in (-pi/2, pi/2].
    """
    c = _validate_cov(cov)
    vals, vecs = np.linalg.eigh(c)
    r = np.sqrt(chi2_radius2(p))
    major = vecs[:, 1]
    angle = float(np.arctan2(major[1], major[0]))
    if angle <= -np.pi / 2:
        angle += np.pi
    elif angle > np.pi / 2:
        angle -= np.pi
    return r * np.sqrt(vals[::-1]), angle


def ellipse_points(mean, cov, p: float, n: int = 241) -> np.ndarray:
    """Closed polygon of the p-mass ellipse of N(mean, cov).

    Parameters
    ----------
    mean : array_like, shape (2,)
        Centre in user units.
    cov : array_like, shape (2, 2)
        Covariance.
    p : float
        Probability mass.
    n : int
        Number of polygon vertices (first equals last).

    Returns
    -------
    numpy.ndarray, shape (n, 2)
        Points with Mahalanobis distance exactly ``sqrt(-2 ln(1 - p))``.
    """
    m = as_array(mean, "mean", shape=(2,))
    c = _validate_cov(cov)
    chol = np.linalg.cholesky(c)
    t = np.linspace(0.0, 2.0 * np.pi, n)
    circle = np.sqrt(chi2_radius2(p)) * np.vstack([np.cos(t), np.sin(t)])
    return (m[:, None] + chol @ circle).T


def mass_outside_box(mean, cov, box, n: int = 2001) -> float:
    """Probability mass of N(mean, cov) in 2-D that lies outside an axis-aligned box.

    The mass inside is ``int_{x0}^{x1} phi_x(x) P(y0 <= Y <= y1 | X = x) dx`` with the
    conditional Gaussian of Y given X; the outer integral is evaluated by the
    trapezoidal rule on ``n`` points over the box's x range clipped to mean +- 10 sd
    (error far below the 1 % that a figure's legend reports).

    Parameters
    ----------
    mean : array_like, shape (2,)
    cov : array_like, shape (2, 2)
        Symmetric positive definite covariance.
    box : array_like, shape (2, 2)
        ``((x0, x1), (y0, y1))``; infinite bounds are allowed.

    Returns
    -------
    float in [0, 1]
    """
    from scipy.stats import norm

    m = as_array(mean, "mean", shape=(2,))
    c = _validate_cov(cov)
    b = np.asarray(box, dtype=float).reshape(2, 2)
    sx = np.sqrt(c[0, 0])
    lo = max(b[0, 0], m[0] - 10 * sx)
    hi = min(b[0, 1], m[0] + 10 * sx)
    if not hi > lo:
        return 1.0
    x = np.linspace(lo, hi, n)
    slope = c[0, 1] / c[0, 0]
    sy = np.sqrt(max(c[1, 1] - slope * c[0, 1], 1e-300))
    my = m[1] + slope * (x - m[0])
    inner = norm.cdf((b[1, 1] - my) / sy) - norm.cdf((b[1, 0] - my) / sy)
    inside = np.trapezoid(norm.pdf(x, m[0], sx) * inner, x)
    return float(np.clip(1.0 - inside, 0.0, 1.0))
