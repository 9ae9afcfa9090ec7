"""RKHS ("surface current") norm between two interfaces.

Each interface is represented as a discrete current: at every cell centre
``c_i`` the normal scaled by the cell measure, ``a_i = |e_i| n_i`` (length in
2D, area in 3D). With the Gaussian kernel of eq:surface_current / eq:surfcurrkernel,

    k(x, y) = exp(-|x - y|^2 / (2 sigma_W^2)),
    <a, b>_V = sum_i sum_j a_i . b_j k(c_i, c_j)                 (eq:inner_prod_rkhs)
    D^2 = <a1, a1>_V - 2 <a1, a2>_V + <a2, a2>_V                (eq:surfcurrontriang)

(the printed double sum in the paper repeats one cross term; the three
distinct terms above are the norm of the difference current, as in the SPEC).
D has units mm^(d-1) * (kernel, dimensionless); it is a scalar.

Discretization
--------------
The double sum is a midpoint quadrature of the continuous current inner
product. With sigma_W (paper: 0.005 mm) below the element length (~0.02 mm)
this quadrature is poor, and the norm between a curve and the *same* curve
with different nodes is as large as a real 0.01 mm offset. Both interfaces are
therefore first subdivided (:meth:`bayescalib.geometry.interface.Interface.resampled`)
so every sub-element is at most ``spacing`` long (curves: by arc length;
triangles: regular subdivision until the longest edge is below the bound).
Default rule: ``spacing = sigma_W / 4``, for which the midpoint rule's
relative error on a Gaussian of width sigma_W is about
``h^2 / (24 sigma_W^2) <= 1/384`` (0.26 %). The geometry is unchanged by the
subdivision, so the result depends on the interfaces, not on their meshes.

Computation
-----------
Pair sums are evaluated block by block (at most ``chunk`` kernel entries in
memory at once) either with NumPy (float64) or with torch (CUDA when
available, else CPU; float64 by default, float32 on request). Squared
distances use the matrix-product expansion ``|x|^2 + |y|^2 - 2 x.y`` after
shifting each block to the mean of its rows, so its cancellation error
``eps |x|^2`` is set by the block radius plus the cut-off (about 15 sigma_W
for the kernel values that matter), not by the position in the domain: about
1e-5 relative kernel error in float32, 1e-14 in float64. The reduction is a
matrix product ``K @ b``, and the self terms use the
symmetry of the kernel (only blocks on and above the diagonal). Block sums are
accumulated in float64. Points are sorted along a Morton (Z-order) curve and,
for each block of rows, only the columns within ``truncate * sigma_W`` (11.9,
i.e. kernel values < 4e-31) of the rows' bounding box are evaluated, which
makes the cost close to linear when sigma_W is small against the interface.
Exponents are clipped to [-80, 0] (no subnormal floats; the clipped values
lie beyond the truncation radius).

Threads: the torch path runs with one intra-op CPU thread by default
(``threads=1``, restored afterwards): on the shared 2-core machine two threads
made the small block products up to 40x slower (``benchmarks/bench_rkhs.py``).
"""

from __future__ import annotations

import math

import numpy as np

from bayescalib.geometry.interface import Interface

__all__ = ["band_grid", "current", "current_field", "default_spacing", "distance_pairs",
           "element_count", "field_grid",
           "field_residual", "naive_rkhs_squared", "pair_sum", "rkhs_distance", "rkhs_squared"]

#: sub-element size relative to sigma_W used when no spacing is given
SPACING_FACTOR = 0.25
#: default maximum number of kernel entries held in memory per block
DEFAULT_CHUNK = 1 << 20
#: below this many kernel pairs the NumPy path is used by backend="auto"
AUTO_NUMPY_PAIRS = 4_000_000
#: kernel truncation radius in units of sigma_W (exp(-11.9^2/2) < 4e-31)
DEFAULT_TRUNCATE = 11.9
#: exponents are clipped to [MIN_EXPONENT, 0]: exp(-80) ~ 1.8e-35 is below the
#: truncation level and keeps float32 out of (slow) subnormal numbers
MIN_EXPONENT = -80.0
#: torch CPU intra-op threads used by the torch path (see pair_sum)
DEFAULT_THREADS = 1
#: most elements :func:`current` resamples an interface into (more: a unit mismatch or a
#: sigma_W far below the interface's size)
MAX_ELEMENTS = 2e6


def default_spacing(sigma_w: float) -> float:
    """Default resampling spacing ``sigma_W / 4`` (mm)."""
    return SPACING_FACTOR * float(sigma_w)


def element_count(interface: Interface, sigma_w: float, spacing: float | None = None
                  ) -> float:
    """Number of elements :func:`current` resamples ``interface`` into (every cell cut
    into pieces of at most ``spacing`` mm; None: ``sigma_w / 4``; inf: the cells as
    they are), without resampling."""
    h = default_spacing(sigma_w) if spacing is None else float(spacing)
    if math.isinf(h):
        return float(interface.n_cells)
    if interface.dim == 2:
        return float(np.sum(np.ceil(interface.measures / h)))
    p = interface.points[interface.cells]
    longest = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2).max(axis=1)
    return float(np.sum(np.ceil(longest / h) ** 2))


def current(
    interface: Interface, sigma_w: float, spacing: float | None = None,
    max_elements: float = MAX_ELEMENTS,
) -> tuple[np.ndarray, np.ndarray]:
    """Centres and measure-scaled normals of the (resampled) interface.

    Parameters
    ----------
    interface : Interface
    sigma_w : float
        Kernel width in mm (> 0).
    spacing : float, optional
        Maximum sub-element size in mm; None -> ``sigma_w / 4``;
        ``math.inf`` -> no resampling (use the cells as given).
    max_elements : float
        Refuse (ValueError) resampling into more elements than this: a sign of
        a unit mismatch or of a sigma_W far below the interface size.

    Returns
    -------
    centres : ndarray, shape (m, d)
    weights : ndarray, shape (m, d)
        ``|e_i| n_i``.
    """
    h = default_spacing(sigma_w) if spacing is None else float(spacing)
    if not (h > 0):
        raise ValueError(f"RKHS spacing must be > 0 (or inf for no resampling), got {spacing}")
    if not math.isinf(h):
        count = element_count(interface, sigma_w, spacing)
        if count > max_elements:
            raise ValueError(
                f"{interface.name}: resampling to spacing {h:g} mm would give {count:.3g} elements "
                f"(limit {max_elements:.3g}); the interface is large compared with sigma_W = "
                f"{sigma_w:g} mm -- check the units, or pass a larger spacing"
            )
        interface = interface.resampled(h)
    return interface.centres, interface.current


def _morton_order(x: np.ndarray, cell: float) -> np.ndarray:
    """Permutation sorting points along a Z-order (Morton) curve of grid ``cell``."""
    d = x.shape[1]
    bits = 63 // d
    g = np.floor((x - x.min(axis=0)) / cell)
    g = np.clip(g, 0, (1 << bits) - 1).astype(np.uint64)
    code = np.zeros(x.shape[0], dtype=np.uint64)
    for bit in range(bits):
        for k in range(d):
            code |= ((g[:, k] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(bit * d + k)
    return np.argsort(code, kind="stable")


def _blocks(x, y, cutoff, rows, symmetric):
    """Row blocks of ``x`` with the columns of ``y`` that can interact.

    Yields ``(i0, i1, cols, n_diag)``: rows ``i0:i1``, column indices ``cols``
    (sorted) of ``y`` within ``cutoff`` of the rows' bounding box, and for
    ``symmetric`` (``x is y``) only columns ``>= i0``, of which the first
    ``n_diag`` are the diagonal block ``i0:i1``.
    """
    n, m = x.shape[0], y.shape[0]
    for i0 in range(0, n, rows):
        i1 = min(n, i0 + rows)
        if cutoff is None:
            cols = np.arange(i0 if symmetric else 0, m)
        else:
            lo = x[i0:i1].min(axis=0) - cutoff
            hi = x[i0:i1].max(axis=0) + cutoff
            yy = y[i0:] if symmetric else y
            inside = np.all((yy >= lo) & (yy <= hi), axis=1)
            cols = np.flatnonzero(inside) + (i0 if symmetric else 0)
        n_diag = int(np.count_nonzero(cols < i1)) if symmetric else 0
        if cols.size:
            yield i0, i1, cols, n_diag


def _block_sum_numpy(xi, ai, yj, bj, inv2s2, symmetric, n_diag):
    centre = xi.mean(axis=0)
    xi = xi - centre
    yj = yj - centre
    d2 = np.sum(xi * xi, axis=1)[:, None] + np.sum(yj * yj, axis=1)[None, :] - 2.0 * (xi @ yj.T)
    kern = np.exp(np.clip(-inv2s2 * d2, MIN_EXPONENT, 0.0))
    kb = kern @ bj
    if symmetric:  # off-diagonal pairs stand for (i, j) and (j, i)
        kb = 2.0 * kb
        if n_diag:
            kb = kb - kern[:, :n_diag] @ bj[:n_diag]
    return float(np.sum(ai * kb))


def _block_sum_torch(xi, ai, yj, bj, inv2s2, symmetric, n_diag):
    import torch

    centre = xi.mean(dim=0)
    xi = xi - centre
    yj = yj - centre
    d2 = torch.addmm(torch.sum(yj * yj, dim=1)[None, :], xi, yj.T, alpha=-2.0)
    d2.add_(torch.sum(xi * xi, dim=1)[:, None])
    kern = d2.mul_(-inv2s2).clamp_(min=MIN_EXPONENT, max=0.0).exp_()
    kb = kern @ bj
    if symmetric:  # off-diagonal pairs stand for (i, j) and (j, i)
        kb = 2.0 * kb
        if n_diag:
            kb = kb - kern[:, :n_diag] @ bj[:n_diag]
    return torch.sum(ai * kb, dtype=torch.float64)


def pair_sum(
    x: np.ndarray,
    a: np.ndarray,
    y: np.ndarray,
    b: np.ndarray,
    sigma_w: float,
    *,
    backend: str = "numpy",
    device: str | None = None,
    dtype: str = "float64",
    chunk: int = DEFAULT_CHUNK,
    symmetric: bool = False,
    truncate: float | None = DEFAULT_TRUNCATE,
    threads: int | None = DEFAULT_THREADS,
) -> float:
    """``sum_i sum_j a_i . b_j exp(-|x_i - y_j|^2 / (2 sigma_w^2))``.

    Parameters
    ----------
    x : ndarray, shape (n, d)
    a : ndarray, shape (n, d)
    y : ndarray, shape (m, d)
    b : ndarray, shape (m, d)
    sigma_w : float
        Kernel width (mm).
    backend : {"numpy", "torch"}
    device : str, optional
        torch device; None -> "cuda" when available, else "cpu".
    dtype : {"float64", "float32"}
        torch working precision (NumPy always uses float64); block sums are
        accumulated in float64.
    chunk : int
        Maximum number of kernel entries per block (bounds the memory).
    symmetric : bool
        ``x is y`` and ``a is b``: evaluate only blocks on/above the diagonal.
    truncate : float or None
        Skip pairs farther apart than ``truncate * sigma_w`` (by block bounding
        boxes after a Morton sort). The default 11.9 drops only kernel values
        ``< exp(-70) ~ 4e-31``, i.e. the result equals the dense sum to double
        precision. None evaluates every pair.
    threads : int or None
        torch intra-op threads on CPU while computing (the previous setting is
        restored). Default 1: the blocks are small matrix products, which
        multi-threading slows down badly on a shared, loaded CPU (measured up
        to 40x), and the pipeline runs one job per core. None keeps the
        global setting.
    """
    inv2s2 = 1.0 / (2.0 * float(sigma_w) ** 2)
    x = np.asarray(x, float)
    a = np.asarray(a, float)
    y = np.asarray(y, float)
    b = np.asarray(b, float)
    cutoff = None if truncate is None else float(truncate) * float(sigma_w)
    if cutoff is not None:
        ox = _morton_order(x, 4.0 * cutoff)
        x, a = x[ox], a[ox]
        if symmetric:
            y, b = x, a
        else:
            oy = _morton_order(y, 4.0 * cutoff)
            y, b = y[oy], b[oy]
    rows = max(1, min(x.shape[0], int(chunk) // max(1, y.shape[0]), 4096))
    if cutoff is not None:
        rows = max(rows, min(x.shape[0], 256))
    if backend == "numpy":
        total = 0.0
        for i0, i1, cols, nd in _blocks(x, y, cutoff, rows, symmetric):
            for c0 in range(0, cols.size, max(1, int(chunk) // (i1 - i0))):
                cc = cols[c0 : c0 + max(1, int(chunk) // (i1 - i0))]
                ndc = max(0, min(nd - c0, cc.size)) if symmetric else 0
                total += _block_sum_numpy(x[i0:i1], a[i0:i1], y[cc], b[cc], inv2s2, symmetric, ndc)
        return total
    if backend != "torch":
        raise ValueError(f"unknown RKHS backend {backend!r}; use 'numpy', 'torch' or 'auto'")
    import torch

    dev = torch.device(device if device else ("cuda" if torch.cuda.is_available() else "cpu"))
    tdt = {"float64": torch.float64, "float32": torch.float32}.get(dtype)
    if tdt is None:
        raise ValueError(f"unknown RKHS dtype {dtype!r}; use 'float64' or 'float32'")
    xt = torch.as_tensor(np.ascontiguousarray(x), dtype=tdt, device=dev)
    at = torch.as_tensor(np.ascontiguousarray(a), dtype=tdt, device=dev)
    if symmetric:
        yt, bt = xt, at
    else:
        yt = torch.as_tensor(np.ascontiguousarray(y), dtype=tdt, device=dev)
        bt = torch.as_tensor(np.ascontiguousarray(b), dtype=tdt, device=dev)
    total = torch.zeros((), dtype=torch.float64, device=dev)
    saved_threads = torch.get_num_threads()
    if dev.type == "cpu" and threads is not None:
        torch.set_num_threads(max(1, int(threads)))
    try:
        _torch_blocks(x, y, xt, at, yt, bt, cutoff, rows, symmetric, chunk, inv2s2, dev, total)
    finally:
        torch.set_num_threads(saved_threads)
    return float(total)


def _torch_blocks(x, y, xt, at, yt, bt, cutoff, rows, symmetric, chunk, inv2s2, dev, total):
    import torch

    with torch.no_grad():
        for i0, i1, cols, nd in _blocks(x, y, cutoff, rows, symmetric):
            step = max(1, int(chunk) // (i1 - i0))
            for c0 in range(0, cols.size, step):
                cc = cols[c0 : c0 + step]
                ndc = max(0, min(nd - c0, cc.size)) if symmetric else 0
                if int(cc[-1]) - int(cc[0]) + 1 == cc.size:  # contiguous: a view
                    yj, bj = yt[int(cc[0]) : int(cc[-1]) + 1], bt[int(cc[0]) : int(cc[-1]) + 1]
                else:
                    idx = torch.as_tensor(cc, device=dev)
                    yj, bj = yt[idx], bt[idx]
                total += _block_sum_torch(xt[i0:i1], at[i0:i1], yj, bj, inv2s2, symmetric, ndc)


def rkhs_squared(
    c1: np.ndarray,
    a1: np.ndarray,
    c2: np.ndarray,
    a2: np.ndarray,
    sigma_w: float,
    *,
    backend: str = "auto",
    device: str | None = None,
    dtype: str = "float64",
    chunk: int = DEFAULT_CHUNK,
    truncate: float | None = DEFAULT_TRUNCATE,
    threads: int | None = DEFAULT_THREADS,
) -> tuple[float, float, float]:
    """The three terms ``(<a1,a1>, <a1,a2>, <a2,a2>)`` of eq:surfcurrontriang.

    Coordinates are shifted to their common mean first (translation invariance
    of the kernel; better conditioned in float32). ``backend="auto"`` uses
    NumPy below ``AUTO_NUMPY_PAIRS`` kernel pairs and torch above.
    """
    if not (np.isfinite(sigma_w) and sigma_w > 0):
        raise ValueError(f"sigma_w must be a positive number (mm), got {sigma_w}")
    c1 = np.asarray(c1, float)
    c2 = np.asarray(c2, float)
    shift = np.vstack([c1, c2]).mean(axis=0)
    c1, c2 = c1 - shift, c2 - shift
    if backend == "auto":
        pairs = (c1.shape[0] + c2.shape[0]) ** 2
        backend = "numpy" if pairs <= AUTO_NUMPY_PAIRS else "torch"
    kw = {"backend": backend, "device": device, "dtype": dtype, "chunk": chunk, "truncate": truncate, "threads": threads}
    s11 = pair_sum(c1, a1, c1, a1, sigma_w, symmetric=True, **kw)
    s12 = pair_sum(c1, a1, c2, a2, sigma_w, **kw)
    s22 = pair_sum(c2, a2, c2, a2, sigma_w, symmetric=True, **kw)
    return s11, s12, s22


#: most kernel pairs one distance may evaluate (about a minute on one core)
DEFAULT_MAX_PAIRS = 1.0e10


def kernel_pairs(c1: np.ndarray, c2: np.ndarray, sigma_w: float,
                 truncate: float | None) -> float:
    """Estimate of the kernel pairs the three sums of D^2 evaluate: all pairs of the
    (n1 + n2) elements, times the fraction within the cut-off ``truncate * sigma_w``
    along the curves' extent (1 without a cut-off)."""
    n = len(c1) + len(c2)
    both = np.vstack([np.asarray(c1, float), np.asarray(c2, float)])
    extent = float(np.max(np.ptp(both, axis=0))) if len(both) else 0.0
    return _pairs(n, extent, sigma_w, truncate)


def _pairs(n: float, extent: float, sigma_w: float, truncate: float | None) -> float:
    frac = 1.0 if truncate is None or extent <= 0 else \
        min(1.0, 2.0 * float(truncate) * float(sigma_w) / extent)
    return float(n) * float(n) * frac


def distance_pairs(obs: Interface, sigma_w: float, spacing: float | None = None,
                   truncate: float | None = DEFAULT_TRUNCATE) -> tuple[float, float, float]:
    """Estimate, before any model interface exists, of the kernel pairs one distance to
    the observed interface ``obs`` evaluates (:func:`kernel_pairs`): its elements after
    resampling (:func:`element_count`) plus those of a model interface as long as it and
    resolved at the spacing, over its extent.

    Returns
    -------
    pairs, n_obs, n_model
        The estimate and the two element counts.
    """
    h = default_spacing(sigma_w) if spacing is None else float(spacing)
    n_obs = element_count(obs, sigma_w, spacing)
    if obs.dim == 2 and not math.isinf(h):
        n_model = float(math.ceil(obs.total_measure / h))
    else:  # a surface: a model mesh like the observed one
        n_model = n_obs
    extent = float(np.max(np.ptp(obs.points, axis=0)))
    return _pairs(n_obs + n_model, extent, sigma_w, truncate), n_obs, n_model


def rkhs_distance(
    model: Interface,
    obs: Interface,
    sigma_w: float,
    *,
    spacing: float | None = None,
    backend: str = "auto",
    device: str | None = None,
    dtype: str = "float64",
    chunk: int = DEFAULT_CHUNK,
    truncate: float | None = DEFAULT_TRUNCATE,
    threads: int | None = DEFAULT_THREADS,
    max_pairs: float = DEFAULT_MAX_PAIRS,
) -> float:
    """RKHS norm D between two interfaces (after resampling; see module docstring).

    Refuses (ValueError) work above ``max_pairs`` kernel pairs (:func:`kernel_pairs`),
    before computing anything.

    Returns
    -------
    float
        ``D = sqrt(max(0, <a1,a1> - 2 <a1,a2> + <a2,a2>))``.
    """
    if model.dim != obs.dim:
        raise ValueError(f"cannot compare a {model.dim}D interface with a {obs.dim}D one")
    c1, a1 = current(model, sigma_w, spacing)
    c2, a2 = current(obs, sigma_w, spacing)
    pairs = kernel_pairs(c1, c2, sigma_w, truncate)
    if pairs > max_pairs:
        raise ValueError(
            f"RKHS: about {pairs:.3g} kernel pairs for {len(c1)} + {len(c2)} elements (limit "
            f"measure.rkhs.max_pairs = {max_pairs:.3g}): the curves hold far more points than "
            f"sigma_W = {sigma_w:g} mm needs (spacing {default_spacing(sigma_w):g} mm is "
            "enough); resample the observed interface, or raise the limit")
    s11, s12, s22 = rkhs_squared(
        c1, a1, c2, a2, sigma_w, backend=backend, device=device, dtype=dtype, chunk=chunk,
        truncate=truncate, threads=threads,
    )
    return math.sqrt(max(0.0, s11 - 2.0 * s12 + s22))


def naive_rkhs_squared(c1, a1, c2, a2, sigma_w: float) -> float:
    """Reference double loop for D^2 (slow; for tests on small cases only)."""
    def inner(x, a, y, b):
        s = 0.0
        for i in range(len(x)):
            for j in range(len(y)):
                d2 = float(np.sum((x[i] - y[j]) ** 2))
                s += float(np.dot(a[i], b[j])) * math.exp(-d2 / (2.0 * sigma_w**2))
        return s

    return inner(c1, a1, c1, a1) - 2.0 * inner(c1, a1, c2, a2) + inner(c2, a2, c2, a2)


# ----------------------------------------------------------------- square-root form
def current_field(centres: np.ndarray, weights: np.ndarray, sigma_w: float,
                  points: np.ndarray, *, chunk: int = DEFAULT_CHUNK) -> np.ndarray:
    """The current smoothed by the kernel's square root, at ``points``: F(z) = sum_i a_i g(z - c_i).

    The Gaussian kernel is a convolution of Gaussians: with
    g(u) = (2 / (pi sigma_W^2))^(d/4) exp(-|u|^2 / sigma_W^2),
    k(x, y) = exp(-|x - y|^2 / (2 sigma_W^2)) = int g(x - z) g(y - z) dz (the Gaussian
    product integral). Hence <a, b>_V = int F_a(z) . F_b(z) dz and
    D^2 = int |F_1(z) - F_2(z)|^2 dz: the RKHS distance is the L2 distance of the
    smoothed currents, and the values of F_1 - F_2 on a grid of spacing h, times
    h^(d/2), are a residual vector whose squared norm is D^2 up to the quadrature
    (:func:`field_grid`): the form an emulator of the model's outputs or a
    Gauss-Newton step needs (``bayescalib.inference.emulator``).

    Parameters
    ----------
    centres, weights : (m, d) the current (:func:`current`).
    sigma_w : kernel width (mm).
    points : (p, d) where F is evaluated (mm).
    chunk : most kernel entries computed at once.

    Returns
    -------
    (p, d) the field F at ``points``.
    """
    c = np.asarray(centres, float)
    a = np.asarray(weights, float)
    z = np.atleast_2d(np.asarray(points, float))
    d = c.shape[1]
    if not (np.isfinite(sigma_w) and sigma_w > 0):
        raise ValueError(f"sigma_w must be a positive number (mm), got {sigma_w}")
    norm = (2.0 / (math.pi * sigma_w**2)) ** (d / 4.0)
    out = np.zeros((z.shape[0], d))
    # |z - c|^2 by the matrix-product expansion about a common origin (the module
    # docstring's cancellation bound: eps |x|^2 / sigma_W^2, 1e-12 for mm-sized domains)
    origin = c.mean(axis=0) if len(c) else np.zeros(d)
    c0, z0 = c - origin, z - origin
    cc = np.sum(c0 * c0, axis=1)
    rows = max(1, int(chunk) // max(c.shape[0], 1))
    for s in range(0, z.shape[0], rows):
        zz = z0[s:s + rows]
        r2 = np.maximum(np.sum(zz * zz, axis=1)[:, None] + cc[None, :] - 2.0 * zz @ c0.T, 0.0)
        out[s:s + rows] = np.exp(-np.minimum(r2 / sigma_w**2, 80.0)) @ a
    return norm * out


def field_grid(lo: np.ndarray, hi: np.ndarray, sigma_w: float,
               spacing_factor: float = 0.5) -> tuple[np.ndarray, float]:
    """A regular grid for :func:`current_field`'s quadrature: the box [lo, hi] (mm)
    widened by 4 sigma_W on every side (g is below 1e-7 of its peak there), spacing
    ``spacing_factor * sigma_W``.

    With spacing h = sigma_W / 2 the trapezoid rule of the Gaussian products in
    D^2 = int |F_1 - F_2|^2 dz errs by about exp(-pi^2 sigma_W^2 / (2 h^2)) = exp(-2 pi^2),
    3e-9 relative (the rule's aliasing error for a Gaussian of sd sigma_W / 2).

    Returns
    -------
    points : (p, d) the grid nodes; weight : h^d, the quadrature weight of each.
    """
    lo = np.asarray(lo, float) - 4.0 * sigma_w
    hi = np.asarray(hi, float) + 4.0 * sigma_w
    h = float(spacing_factor) * float(sigma_w)
    axes = [np.arange(l0, h1 + h, h) for l0, h1 in zip(lo, hi)]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([m.ravel() for m in mesh]), h ** lo.size


def band_grid(obs: Interface, sigma_w: float, band: float = 8.0,
              spacing: float = 0.75) -> tuple[np.ndarray, float]:
    """The nodes of :func:`field_grid` (spacing ``spacing * sigma_W``) that lie within
    ``band * sigma_W`` of the observed interface, and the quadrature weight h^d.

    The grid depends on the observed interface and sigma_W only, so every solve's
    residual (:func:`field_residual`) has the same length and meaning. The smoothed
    current of an interface is below 1e-7 of its peak 4 sigma_W away from it, so a model
    interface within (band - 4) sigma_W of the observed one lies wholly in the band.
    """
    from bayescalib.geometry.projection import closest_points

    if not (band > 0 and spacing > 0):
        raise ValueError(f"the field band and spacing must be > 0 (units of sigma_W), got "
                         f"{band} and {spacing}")
    pts = np.asarray(obs.points, float)
    grid, weight = field_grid(pts.min(axis=0) - (band - 4.0) * sigma_w,
                              pts.max(axis=0) + (band - 4.0) * sigma_w, sigma_w,
                              spacing_factor=spacing)
    dist = np.abs(closest_points(grid, obs)[0])
    return grid[dist <= band * sigma_w], weight


def field_residual(model: Interface, obs: Interface, sigma_w: float, D: float, *,
                   spacing: float | None = None, band: float = 8.0,
                   field_spacing: float = 0.75) -> np.ndarray:
    """A residual vector of the RKHS measure: r with |r| = D, most of it resolved in space.

    The smoothed currents' difference F_model - F_obs (:func:`current_field`, both
    interfaces resampled as for D) at the nodes of :func:`band_grid`, times the square
    root of the quadrature weight, flattened (p d values), then one last entry
    sqrt(max(D^2 - |grid part|^2, 0)): the part of D^2 the band does not hold (a model
    interface partly outside it). So |r|^2 = D^2 to the quadrature's error (the trapezoid
    rule of Gaussians of sd sigma_W / 2 with spacing 0.75 sigma_W: about 3e-4 relative,
    by which the grid part may exceed D^2 and the last entry is then 0).

    Parameters
    ----------
    model, obs : the interfaces (mm).
    sigma_w : kernel width (mm).
    D : their RKHS distance (:func:`rkhs_distance`).
    spacing : the resampling spacing of :func:`current`.
    band, field_spacing : :func:`band_grid`'s band half-width and grid spacing (sigma_W).

    Returns
    -------
    (p d + 1,) the residual (units of D).
    """
    grid, weight = band_grid(obs, sigma_w, band, field_spacing)
    c1, a1 = current(model, sigma_w, spacing)
    c2, a2 = current(obs, sigma_w, spacing)
    diff = (current_field(c1, a1, sigma_w, grid) - current_field(c2, a2, sigma_w, grid)).ravel()
    diff *= math.sqrt(weight)
    rest = math.sqrt(max(float(D) ** 2 - float(diff @ diff), 0.0))
    return np.concatenate([diff, [rest]])
