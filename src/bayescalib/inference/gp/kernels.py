"""The stationary kernels of the GP surrogate (paper App. D).

Model (eq. prior_gp, eq. matern32)
    L(x) ~ GP(m, k),   k(x, x') = s^2 (1 + sqrt(3) r) exp(-sqrt(3) r),
    r = || (u - u') / l ||_2,

on *unit-box-scaled* inputs u = (x - lo) / (hi - lo): each input is mapped
to [0, 1] by the design box (``bounds``; when not given, by the min/max of the
training inputs). ``ard=False`` uses one length scale l for all scaled inputs
(the paper's 2D case); ``ard=True`` one per input (the paper's 6D/7D case).
Besides the paper's Matérn 3/2, :data:`KERNELS` holds Matérn 5/2 and the squared
exponential, all of the form k(r) = s^2 f(c r) (``surrogate.kernel``; ``auto``
chooses among them by the evidence, :mod:`bayescalib.inference.gp.selection`).

The GP's inputs u may also be log inputs and rotated to a principal-axes frame
(:mod:`bayescalib.inference.gp.inputs`); the kernel sees u alone.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["KERNELS", "kernel_matrix", "matern32"]

_SQRT3 = math.sqrt(3.0)


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
