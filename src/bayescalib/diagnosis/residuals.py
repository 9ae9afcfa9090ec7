"""Posterior predictive check of the calibrated model along the observed interface.

(The *predictive check*; not the rounds' posterior check: docs/glossary.md.)

Steps 1 (check) and 2 (locate) of the model-form diagnosis. All quantities are
*normal offsets* in mm measured along the observed interface's arc length ``s``:

* the reference curve ``C_bar`` is the node-wise mean of the predicted interfaces of
  K posterior draws (all draws share the model's interface nodes);
* the observed residual at observed node ``x_j`` is its signed distance to ``C_bar``,
  ``y_j = (x_j - p_j) . n_j`` with ``p_j`` the closest point on ``C_bar`` and ``n_j``
  the normal there, oriented into the fluid (positive: the observed interface lies
  outside the predicted biofilm);
* draw ``k`` sits at offset ``o_kj`` from ``C_bar`` at ``p_j`` (minus the signed distance
  of ``p_j`` to draw ``k``'s interface).

Posterior predictive distribution (paper Sec. 2.1, with the observation noise of
eq:noisy_data): a replicate of ``y_j`` is ``o_kj + sigma eps_j``, ``eps_j ~ N(0, 1)``
i.i.d., for a random draw ``k``. Its mean and variance are ``mu_j = mean_k o_kj`` and
``v_j = var_k o_kj + sigma^2``; the pointwise band is ``mu_j +- z_(1-a/2) sqrt(v_j)``
and the simultaneous band ``mu_j +- c sqrt(v_j)`` with ``c`` the (1 - a) quantile of
``max_j |y_rep_j - mu_j| / sqrt(v_j)`` over replicates.

Model-form errors are smooth along the interface while noise is white, so the residual
is also smoothed with a Gaussian kernel of width ``ell`` in arc length (matrix ``S``,
rows normalized); the smoothed replicates ``S o_k + sigma S eps`` give the bands of the
smoothed residual, and the located mismatch is where the smoothed residual leaves its
simultaneous band. Where the mismatch is large that band test marks nearly the whole
interface (every node is significant); the located *core* says where it is largest:
the located nodes whose smoothed residual is at least half its largest value over all
snapshots (a half-maximum width, the same rule as the effect regions the concealed
benchmark scores it against).

Global test: posterior predictive p-values ``P(T(y_rep) >= T(y))`` of three
discrepancy statistics — ``chi2 = sum_j (y_j - mu_j)^2 / v_j``, the largest
standardized residual, and the largest standardized *smoothed* residual — over
``K x L`` replicates (L noise draws per posterior draw). The model is declared
inadequate when the smallest p-value is below ``alpha / 3`` (Bonferroni).

Noise model of the replicates (``noise_model``):

* ``gaussian`` — ``eps_j ~ N(0, 1)`` i.i.d. per node, scaled by ``sigma`` (below). Right
  for synthetic coordinate noise, where it is exact.
* ``bootstrap`` — the noise is resampled from the data (:func:`noise_pool`,
  :func:`resample_noise`). The residual ``r = y - mu`` is split into its smooth part
  ``S r`` (the Gaussian smoother of width ``ell``, the scale at which the check looks
  for a mismatch) and its rough part; a model-form or calibration error is smooth and
  stays in ``S r``. The pool holds the leave-one-out residuals
  ``(r_j - (S r)_j) / (1 - S_jj)`` (``r_j`` minus the smoother's prediction of it from
  the other nodes: a single speckle dent keeps its full size) of all snapshots,
  centred. Every replicate's noise is drawn from the pool with replacement, node by
  node, plus Gaussian jitter of Silverman's bandwidth (a smoothed bootstrap: the
  largest of ~100 pooled values is below what a replicate should sometimes reach).
  The replicates so carry the data's own marginal, heavy tails included, and its own
  level: a Gaussian of a plug-in ``sigma`` (a MAD of ~50 second differences per
  snapshot, 0.6-1.6 x the segmentation error's RMS on null renders) makes ``chi2``
  fire whenever the estimate is low. ``sigma`` is the pool's RMS (when given, the
  pool is rescaled to it). For white noise a pooled value has a variance a little
  above ``sigma^2`` (by ``sum_(k!=j) S_jk^2 / (1 - S_jj)^2``, ~0.16 at two node
  spacings per ``ell``) and the jitter adds ~0.13 ``sigma^2`` (100 values): the
  bootstrap check is a little conservative. A real
  effect is not resampled into the replicates: its smooth part is taken out first, so
  the observed statistics carry it and the replicates do not. Limitation: an effect
  whose scale along the interface is below ``ell`` is partly taken for noise (it
  widens the replicates). The nodes' noise must be independent: the diagnosis thins
  image-traced nodes to one per correlation length (``diagnose.noise_lag``); noise
  still correlated between the used nodes (AR(1) with 0.3 between neighbours) makes
  the bootstrap check fire too often (measured 12 % at alpha 5 %; resampling blocks
  of 3 nodes does not help: the leave-one-out residual loses the correlated part).
  Measured calibration and power: ``benchmarks/image_noise.py``.

Noise level ``sigma``: given (the known observation noise), or estimated from the
residual by the difference-based MAD estimator ``1.4826 median|dy - median dy| /
sqrt(2)`` (differences of neighbouring residuals cancel a smooth mismatch), floored at
``noise_floor`` (the mesh error of the interface, ~1e-4 mm) and, for interfaces
segmented from raw scans, at the segmentation's own positional uncertainty
(``segmentation_sigma``, :mod:`bayescalib.geometry.imaging`: the image noise over the
intensity gradient across the contour, with the pixel quantisation): the residual cannot
be less noisy than the tracing of the data, and a data-based estimate from ~100 thinned
nodes can come out low by chance. ``sigma_source`` is then ``"segmentation (lower
bound)"``, and both values are reported (``sigma_data_mm``, ``sigma_segmentation_mm``).
(Second differences
``y_(j-1) - 2 y_j + y_(j+1)`` of white noise have variance ``6 sigma^2`` and cancel the
linear part of a smooth mismatch.)

**On a 3D surface** (the 3D model's interface) the same check, with three changes. The
observed nodes have no order: the residual's place along the interface is the node
itself (:func:`node_coordinates`) and the smoother's kernel takes the straight
distance between nodes (:func:`node_distances`; within 0.2 % of the distance along the
colony's surface at the default ``ell``). The noise estimate compares each node with
the mean of its nearest neighbours (:func:`estimate_surface_noise`) instead of second
differences along a curve. A located mismatch is a connected region of nodes outside
the band (:func:`surface_regions`) instead of an interval of arc length, reported
with its extent in x, y and z and its place on the colony in words
(:func:`colony_place`: near the top, or which flank). The diagnosis thins a surface's
nodes to a Poisson-disk subset (:func:`thin_nodes`), which also keeps the
``n x n`` smoother small: a surface segmented from a volume has 10^4 vertices.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtri

from bayescalib.geometry.interface import Interface
from bayescalib.geometry.projection import closest_points
from bayescalib.geometry.registration import REGISTRATION_MODES

__all__ = [
    "NOISE_MODELS",
    "PredictiveCheck",
    "SnapshotCheck",
    "arc_length",
    "colony_place",
    "estimate_noise",
    "estimate_surface_noise",
    "fluid_side_sign",
    "intervals",
    "kernel_bandwidth",
    "node_coordinates",
    "node_distances",
    "noise_pool",
    "offsets",
    "predictive_check",
    "registration_signatures",
    "resample_noise",
    "rms_spread",
    "smoother",
    "surface_regions",
    "thin_nodes",
]


def arc_length(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length (mm) of an ordered polyline, shape (n,)."""
    pts = np.asarray(points, dtype=float)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])


def fluid_side_sign(curve: Interface) -> float:
    """+1 if the curve's normals point up (into the fluid above the biofilm) at its
    highest node, else -1; multiplies signed distances so that + means 'into the fluid'."""
    top = int(np.argmax(curve.centres[:, 1]))
    return 1.0 if curve.normals[top, 1] >= 0 else -1.0


def offsets(observed: np.ndarray, reference: Interface,
            others: Sequence[Interface]) -> tuple[np.ndarray, np.ndarray]:
    """Normal offsets along the observed nodes.

    Parameters
    ----------
    observed
        (n, 2) observed interface nodes, mm.
    reference
        The reference curve (e.g. the mean prediction).
    others
        Curves whose offsets from ``reference`` are wanted (e.g. posterior draws).

    Returns
    -------
    y : (n,)
        Signed distance of each observed node to ``reference`` (+ into the fluid).
    o : (len(others), n)
        Offset of each other curve from ``reference`` at the closest points ``p_j``.
    """
    sgn = fluid_side_sign(reference)
    y, p, _ = closest_points(np.asarray(observed, dtype=float), reference)
    y = sgn * y
    o = np.empty((len(others), len(y)))
    for k, curve in enumerate(others):
        d, _, _ = closest_points(p, curve)
        o[k] = -fluid_side_sign(curve) * d
    return y, o


def registration_signatures(observed: np.ndarray, reference: Interface, centre: np.ndarray,
                            modes: Sequence[str]) -> np.ndarray:
    """Change of the residual ``y`` of :func:`offsets` per unit misregistration.

    If the observed nodes are misplaced by ``delta(x) = t + theta R_90 (x - c) +
    s (x - c)`` (shift ``t``, small rotation ``theta`` and scale ``s`` about the centre
    ``c``), their signed distance to the reference changes by ``n . delta`` to first
    order, with ``n`` the unit normal (+ into the fluid) at the closest point.

    Parameters
    ----------
    observed
        (n, 2) observed nodes, mm.
    reference
        The reference curve of the residual (e.g. the posterior-mean prediction).
    centre
        (2,) centre of rotation and scaling, mm.
    modes
        Subset of :data:`REGISTRATION_MODES`, in the column order wanted.

    Returns
    -------
    ndarray, shape (n, len(modes))
        mm per mm (shifts), mm per rad (rotation), mm per unit relative scale.
    """
    obs = np.asarray(observed, dtype=float)
    _, _, cell = closest_points(obs, reference)
    nrm = fluid_side_sign(reference) * reference.normals[cell]
    d = obs - np.asarray(centre, dtype=float)
    cols = {"shift_x": nrm[:, 0], "shift_y": nrm[:, 1],
            "rotation": -nrm[:, 0] * d[:, 1] + nrm[:, 1] * d[:, 0],
            "scale": np.sum(nrm * d, axis=1)}
    unknown = [m for m in modes if m not in cols]
    if unknown:
        raise ValueError(f"registration modes {unknown} unknown; choose from {REGISTRATION_MODES}")
    return np.column_stack([cols[m] for m in modes]) if modes else np.zeros((len(obs), 0))


def node_coordinates(points: np.ndarray) -> np.ndarray:
    """Where the observed nodes lie along the interface, for the smoother and the located
    regions: the arc length (n,) of a 2D curve's ordered nodes (:func:`arc_length`); on a
    3D surface the nodes themselves, (n, 3) (:func:`node_distances`)."""
    pts = np.asarray(points, dtype=float)
    return arc_length(pts) if pts.shape[1] == 2 else pts


def node_distances(coord: np.ndarray) -> np.ndarray:
    """Distances between the nodes along the interface, shape (n, n), mm.

    ``coord`` from :func:`node_coordinates`: along a curve the difference of arc
    lengths; across a surface the straight distance between the nodes, which is the
    distance along the surface to within ``d^3 / (24 R^2)`` for a radius of curvature
    ``R`` (0.2 % at ``d = ell = 0.05`` mm on a colony of radius 0.3 mm)."""
    from scipy.spatial.distance import cdist

    c = np.asarray(coord, dtype=float)
    if c.ndim == 1:
        return np.abs(c[:, None] - c[None, :])
    return cdist(c, c)


def smoother(coord: np.ndarray, ell: float) -> np.ndarray:
    """Row-normalized Gaussian kernel smoother along the interface, shape (n, n).

    ``coord``: arc length (n,) of a curve's nodes or a surface's nodes (n, 3)
    (:func:`node_coordinates`); the kernel is ``exp(-d^2 / (2 ell^2))`` of their
    distances (:func:`node_distances`)."""
    c = np.asarray(coord, dtype=float)
    if ell <= 0:
        return np.eye(c.shape[0])
    K = np.exp(-0.5 * (node_distances(c) / ell) ** 2)
    return K / K.sum(axis=1, keepdims=True)


#: noise models of the predictive check's replicates (see the module docstring)
NOISE_MODELS = ("gaussian", "bootstrap")


def noise_pool(residuals: Sequence[np.ndarray], coordinates: Sequence[np.ndarray],
               ell: float) -> np.ndarray:
    """Rough part of the residuals, pooled over snapshots: the values the ``bootstrap``
    noise model resamples.

    Parameters
    ----------
    residuals
        Per snapshot, the residual to the predicted interface at its nodes, (n_i,), mm.
    coordinates
        Per snapshot, the nodes' place along the interface (:func:`node_coordinates`):
        arc length (n_i,) of a curve, the nodes (n_i, 3) of a surface, mm.
    ell
        Width of the Gaussian smoother (:func:`smoother`) whose output is the smooth
        part, mm (> 0).

    Returns
    -------
    ndarray, shape (sum n_i,)
        Leave-one-out smoothing residuals ``(r_j - (S r)_j) / (1 - S_jj)`` — ``r_j``
        minus the smoother's prediction of it from the *other* nodes, so a single
        outlier (a speckle dent) keeps its full size — snapshot after snapshot,
        centred to mean 0, mm. A smooth mismatch (scale well above ``ell``) is removed.
    """
    if not ell > 0:
        raise ValueError(f"the noise pool needs a smoothing length ell > 0 mm, got {ell}")
    parts = []
    for r, s in zip(residuals, coordinates, strict=True):
        r = np.asarray(r, dtype=float)
        S = smoother(s, ell)
        lev = 1.0 - np.diag(S)
        if r.size < 3 or np.any(lev <= 1e-3):
            raise ValueError("the smoother leaves no rough part of the residual (too few nodes "
                             "per smoothing length): the bootstrap noise model needs nodes a "
                             "fraction of the smoothing length apart")
        parts.append((r - S @ r) / lev)
    pool = np.concatenate(parts)
    return pool - pool.mean()


def kernel_bandwidth(pool: np.ndarray) -> float:
    """Silverman's rule-of-thumb bandwidth of a Gaussian kernel density of ``pool``,
    ``0.9 min(sd, IQR / 1.349) N^(-1/5)`` (same unit as ``pool``)."""
    pool = np.asarray(pool, dtype=float)
    q75, q25 = np.quantile(pool, [0.75, 0.25])
    spread = min(float(np.std(pool)), float(q75 - q25) / 1.349) or float(np.std(pool))
    return 0.9 * spread * pool.size ** (-0.2)


def resample_noise(pool: np.ndarray, shape: tuple[int, ...],
                   rng: np.random.Generator) -> np.ndarray:
    """Smoothed bootstrap of ``pool``: draws with replacement plus Gaussian jitter of
    :func:`kernel_bandwidth` (draws from a kernel density of the pool, whose tails reach
    past the pool's extremes).

    Parameters
    ----------
    pool
        (N,) values to resample (:func:`noise_pool`), mm.
    shape
        Shape of the replicates wanted, e.g. ``(K, L, n)``.
    rng
        Random generator.

    Returns
    -------
    ndarray, shape ``shape``, mm.
    """
    pool = np.asarray(pool, dtype=float)
    if pool.size < 2:
        raise ValueError(f"the noise pool needs at least 2 values, got {pool.size}")
    out = pool[rng.integers(0, pool.size, size=shape)]
    return out + kernel_bandwidth(pool) * rng.standard_normal(shape)


def estimate_noise(y: np.ndarray, floor: float = 0.0, lag: int = 1) -> float:
    """Robust estimate of the noise in a smooth residual, mm: the MAD of its second
    differences ``y[i-lag] - 2 y[i] + y[i+lag]``, scaled to a standard deviation.

    ``lag = 1`` (adjacent nodes) is right for white noise. Interfaces traced from a
    segmented image need a lag of a few pixels: their nodes sit on pixel edges, so
    neighbouring nodes share one quantisation step (most lag-1 differences are exactly
    0 and the MAD collapses) and the segmentation error is correlated over the blur;
    at a lag of about 5 pixels the estimate is the error's RMS (``tests/test_imaging.py``).
    """
    yy = np.asarray(y, dtype=float)
    k = int(lag)
    if k < 1:
        raise ValueError(f"lag must be >= 1 node, got {lag}")
    d = yy[2 * k:] - 2.0 * yy[k:-k] + yy[:-2 * k] if yy.size > 2 * k else np.empty(0)
    if d.size < 3:
        return float(floor)
    mad = np.median(np.abs(d - np.median(d)))
    return float(max(1.4826 * mad / np.sqrt(6.0), floor))


def _lag_nodes(points: np.ndarray, length: float) -> int:
    """Nodes spanning at least ``length`` mm at the median node spacing (>= 1)."""
    if not (np.isfinite(length) and length >= 0):
        raise ValueError(f"noise_lag must be >= 0 mm, got {length}")
    step = np.linalg.norm(np.diff(np.asarray(points, dtype=float), axis=0), axis=1)
    h = float(np.median(step)) if step.size else 0.0
    return max(1, int(np.ceil(length / h - 1e-9))) if h > 0 and length > 0 else 1


def thin_nodes(points: np.ndarray, spacing: float) -> np.ndarray:
    """Indices of the observed nodes kept when they are thinned to one per ``spacing``
    mm (``spacing = 0`` keeps all).

    An ordered 2D polyline keeps the first node, then the first node at or beyond each
    multiple of ``spacing`` of arc length, and the last node. A 3D surface's nodes
    (``(n, 3)``, no order) are thinned greedily in index order: a node is kept unless a
    kept node lies within ``spacing`` (a Poisson-disk subset: kept nodes are at least
    ``spacing`` apart, and every node lies within ``spacing`` of a kept one).

    The predictive check treats the observed nodes' noise as independent: nodes traced
    from an image carry a segmentation error correlated over a few pixels, which the
    check would take for a mismatch; nodes one correlation length apart are (about)
    independent.
    """
    pts = np.asarray(points, dtype=float)
    if not (np.isfinite(spacing) and spacing >= 0):
        raise ValueError(f"spacing must be >= 0 mm, got {spacing}")
    if spacing == 0 or pts.shape[0] < 3:
        return np.arange(pts.shape[0])
    if pts.shape[1] == 3:
        from scipy.spatial import cKDTree

        tree = cKDTree(pts)
        blocked = np.zeros(pts.shape[0], dtype=bool)
        keep = []
        for i in range(pts.shape[0]):
            if not blocked[i]:
                keep.append(i)
                # strictly closer than spacing (a node exactly spacing away stays free)
                blocked[tree.query_ball_point(pts[i], float(spacing) * (1.0 - 1e-9))] = True
        return np.asarray(keep, dtype=np.int64)
    s = arc_length(pts)
    idx = np.searchsorted(s, np.arange(0.0, s[-1], float(spacing)))
    return np.unique(np.r_[idx, pts.shape[0] - 1])


#: nearest neighbours of a surface node whose mean residual it is compared with
#: (:func:`estimate_surface_noise`)
NOISE_NEIGHBOURS = 6


def estimate_surface_noise(y: np.ndarray, points: np.ndarray, floor: float = 0.0) -> float:
    """Robust estimate of the noise in a smooth residual on a surface's nodes, mm.

    The surface analogue of :func:`estimate_noise`: each node's residual minus the mean
    of its :data:`NOISE_NEIGHBOURS` nearest nodes, ``d_j = y_j - mean_k y_k``, cancels a
    mismatch that is smooth over the neighbours' distance (a linear one where they
    surround the node) and has, for white noise, the variance ``sigma^2 (1 + 1/k)``; the
    MAD of ``d`` scaled to that. Correlated noise is handled by thinning the nodes
    first (:func:`thin_nodes`: the neighbours are then a correlation length apart).

    Parameters
    ----------
    y
        (n,) residual at the nodes, mm.
    points
        (n, 3) the nodes, mm.
    floor
        Lower bound of the estimate, mm.
    """
    from scipy.spatial import cKDTree

    yy = np.asarray(y, dtype=float)
    pts = np.asarray(points, dtype=float)
    k = NOISE_NEIGHBOURS
    if yy.size < k + 3:
        return float(floor)
    _, nb = cKDTree(pts).query(pts, k=k + 1)
    d = yy - yy[nb[:, 1:]].mean(axis=1)
    mad = np.median(np.abs(d - np.median(d)))
    return float(max(1.4826 * mad / np.sqrt(1.0 + 1.0 / k), floor))


#: surface nodes closer than this many median nearest-neighbour distances are
#: neighbours in a located region (:func:`surface_regions`): the thinned nodes' nearest
#: neighbours lie 1-2 thinning spacings apart, so a region is one piece where its
#: nodes are
REGION_LINK = 1.6


def surface_regions(mask: np.ndarray, points: np.ndarray) -> list[np.ndarray]:
    """Connected pieces of the marked nodes of a surface, the surface analogue of
    :func:`intervals`.

    Two marked nodes are joined when they lie less than :data:`REGION_LINK` median
    nearest-neighbour distances (over all nodes) apart.

    Parameters
    ----------
    mask
        (n,) bool, the marked nodes.
    points
        (n, 3) the nodes, mm.

    Returns
    -------
    list of ndarray
        The node indices of each piece (sorted), largest piece first.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    m = np.asarray(mask, dtype=bool)
    idx = np.flatnonzero(m)
    if idx.size == 0:
        return []
    pts = np.asarray(points, dtype=float)
    nn, _ = cKDTree(pts).query(pts, k=2)
    link = REGION_LINK * float(np.median(nn[:, 1]))
    pairs = cKDTree(pts[idx]).query_pairs(link, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])) if len(pairs) else
                       (np.zeros(0), (np.zeros(0, int), np.zeros(0, int))),
                       shape=(idx.size, idx.size))
    _, lab = connected_components(graph, directed=False)
    pieces = [idx[lab == c] for c in np.unique(lab)]
    return sorted(pieces, key=lambda p: (-p.size, int(p[0])))


#: the located *core*: the nodes of the located intervals whose smoothed residual is at
#: least this share of the largest smoothed residual over all located nodes (all snapshots)
CORE_SHARE = 0.5


def intervals(mask: np.ndarray, s: np.ndarray, min_gap: int = 1) -> list[tuple[int, int]]:
    """Runs of ``True`` in ``mask`` as inclusive node index pairs; runs separated by at
    most ``min_gap`` ``False`` nodes are merged."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return []
    runs = [[idx[0], idx[0]]]
    for i in idx[1:]:
        if i - runs[-1][1] <= min_gap + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return [(int(a), int(b)) for a, b in runs]


@dataclass
class SnapshotCheck:
    """Predictive check of one snapshot (arrays over the observed nodes).

    Attributes
    ----------
    label
        Snapshot label.
    s, xy
        Arc length (mm; None on a 3D surface, whose nodes have no order) and
        coordinates (n, 2) or (n, 3) of the observed nodes.
    y, mu, v
        Observed residual, predictive mean and variance (mm, mm^2).
    y_s, mu_s, v_s
        The same for the smoothed residual.
    z, z_s
        Standardized residuals ``(y - mu)/sqrt(v)`` and smoothed.
    """

    label: str
    s: np.ndarray
    xy: np.ndarray
    y: np.ndarray
    mu: np.ndarray
    v: np.ndarray
    y_s: np.ndarray
    mu_s: np.ndarray
    v_s: np.ndarray
    z: np.ndarray = field(init=False)
    z_s: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.z = (self.y - self.mu) / np.sqrt(self.v)
        self.z_s = (self.y_s - self.mu_s) / np.sqrt(self.v_s)


@dataclass
class PredictiveCheck:
    """Result of :func:`predictive_check`.

    Attributes
    ----------
    snapshots
        One :class:`SnapshotCheck` per snapshot.
    sigma
        Noise standard deviation used, mm; ``sigma_source`` says where it came from.
    c_pointwise, c_simultaneous, c_smooth
        Band half-widths in standard deviations (pointwise normal quantile; simultaneous
        for the raw and the smoothed residual).
    statistics, p_values
        Observed statistics and posterior predictive p-values (``chi2``, ``max_abs``,
        ``max_abs_smooth``).
    adequate
        False when ``min(p) < alpha / 3``.
    located
        Mismatch intervals: dicts with snapshot, node range, arc-length range (mm),
        bounding box (mm), peak standardized smoothed residual and its sign, and the
        interval's *core* (``core_nodes``, ``core_arc_length_mm``: the runs of nodes
        whose smoothed residual ``|y_s - mu_s|`` is at least :data:`CORE_SHARE` of its
        largest value over all located nodes of all snapshots; empty where the interval
        stays below it). On a 3D surface, regions instead of intervals: their
        ``node_indices``, ``x_mm``, ``y_mm``, ``z_mm`` ranges, ``peak_mm`` and ``where``
        on the colony (:func:`colony_place`), ``core_node_indices`` and ``core_where``.
    rms
        Root mean square of the observed residual ``y - mu`` over all nodes, mm.
    coverage
        Fraction of nodes whose observed residual lies in the pointwise band.
    noise_lag
        Arc length (mm) of the differences the noise estimate used (when estimated).
    sigma_data, sigma_segmentation
        When a segmentation uncertainty was given: the data-based estimate (mm; None
        when ``sigma`` was given) and the segmentation's positional uncertainty (mm).
    noise_model
        Noise model of the replicates (:data:`NOISE_MODELS`).
    noise_pool
        ``bootstrap``: size, RMS (mm, after any rescaling to a given ``sigma``) and
        kurtosis of the resampled values (3 for Gaussian noise); ``None`` otherwise.
    rms_spread
        How ``rms`` varies with the posterior draws (:func:`rms_spread`): the number of
        draws, the median and 16-84 % range of the per-draw RMS (each draw's own
        prediction against the observations, mm) and the 16-84 % bootstrap interval of
        ``rms`` over draws resampled with replacement (mm).
    """

    snapshots: list[SnapshotCheck]
    sigma: float
    sigma_source: str
    alpha: float
    c_pointwise: float
    c_simultaneous: float
    c_smooth: float
    statistics: dict[str, float]
    p_values: dict[str, float]
    adequate: bool
    located: list[dict]
    rms: float
    coverage: float
    noise_lag: float = 0.0
    noise_model: str = "gaussian"
    noise_pool: dict | None = None
    rms_spread: dict | None = None
    sigma_data: float | None = None
    sigma_segmentation: float | None = None

    def to_json(self) -> dict:
        """Plain-value summary (no per-node arrays)."""
        seg = ({} if self.sigma_segmentation is None else
               {"sigma_data_mm": self.sigma_data,
                "sigma_segmentation_mm": self.sigma_segmentation})
        return {
            "adequate": bool(self.adequate), "alpha": self.alpha,
            "sigma_mm": self.sigma, "sigma_source": self.sigma_source, **seg,
            "noise_lag_mm": self.noise_lag,
            "noise_model": {"name": self.noise_model,
                            **({"pool": self.noise_pool} if self.noise_pool else {})},
            "statistics": self.statistics, "p_values": self.p_values,
            "band_sd": {"pointwise": self.c_pointwise, "simultaneous": self.c_simultaneous,
                        "smoothed_simultaneous": self.c_smooth},
            "residual_rms_mm": self.rms, "residual_rms_spread": self.rms_spread,
            "pointwise_band_coverage": self.coverage,
            "located": self.located,
        }


#: bootstrap resamples of the posterior draws for the interval of the residual RMS
N_RMS_BOOTSTRAP = 400


def rms_spread(y: Sequence[np.ndarray], o: Sequence[np.ndarray], rng: np.random.Generator,
               n_boot: int = N_RMS_BOOTSTRAP) -> dict:
    """Spread of the residual RMS over the posterior draws it was computed from.

    The check's RMS is that of the observed residual against the draws' mean prediction
    (``y - mean_k o_k`` over all nodes). With K draws it is itself an estimate: a
    different set of draws of the same posterior gives another value. Two spreads:

    * *per draw*: the RMS of each draw's own prediction against the observations,
      ``sqrt(mean(y - o_k)^2)`` over all nodes; median and 16-84 % range over the K
      draws (what a single posterior draw fits to);
    * *bootstrap*: the RMS against the mean prediction of K draws resampled with
      replacement, ``n_boot`` times; its 16-84 % range is a 68 % interval of the
      reported RMS under the sampling of the draws (Efron's percentile interval).

    Parameters
    ----------
    y
        Per snapshot, (n_i,) observed residual against the mean prediction, mm.
    o
        Per snapshot, (K, n_i) offsets of the K draws from the mean prediction, mm.
    rng
        Random generator (bootstrap).
    n_boot
        Bootstrap resamples.

    Returns
    -------
    dict
        ``n_draws``, ``per_draw_median_mm``, ``per_draw_q16_mm``, ``per_draw_q84_mm``,
        ``bootstrap_q16_mm``, ``bootstrap_q84_mm``, ``n_bootstrap``.
    """
    Y = np.concatenate([np.asarray(v, float) for v in y])
    O = np.concatenate([np.asarray(v, float) for v in o], axis=1)  # (K, n)
    K = O.shape[0]
    per = np.sqrt(np.mean((Y[None, :] - O) ** 2, axis=1))
    idx = rng.integers(0, K, size=(int(n_boot), K))
    boot = np.array([np.sqrt(np.mean((Y - O[i].mean(axis=0)) ** 2)) for i in idx])
    q = np.quantile
    return {"n_draws": int(K), "per_draw_median_mm": float(np.median(per)),
            "per_draw_q16_mm": float(q(per, 0.16)), "per_draw_q84_mm": float(q(per, 0.84)),
            "bootstrap_q16_mm": float(q(boot, 0.16)), "bootstrap_q84_mm": float(q(boot, 0.84)),
            "n_bootstrap": int(n_boot)}


def predictive_check(
    observed: Sequence[Interface],
    draws: Sequence[Sequence[Interface]],
    *,
    labels: Sequence[str] | None = None,
    sigma: float | None = None,
    noise_floor: float = 1.0e-4,
    ell: float = 0.05,
    alpha: float = 0.05,
    n_noise: int = 64,
    noise_lag: float = 0.0,
    noise_model: str = "gaussian",
    segmentation_sigma: float | None = None,
    rng: np.random.Generator,
) -> PredictiveCheck:
    """Posterior predictive check of interfaces (see the module docstring).

    Parameters
    ----------
    observed
        Observed interfaces, one per snapshot (2D polylines or 3D surfaces, mm), or
        their nodes (arrays (n, 2) in curve order, or (n, 3)).
    draws
        ``draws[k][i]``: predicted interface of posterior draw ``k`` for snapshot ``i``;
        all draws of one snapshot share their nodes (at least 2 draws).
    labels
        Snapshot labels.
    sigma
        Observation noise standard deviation (mm); ``None`` estimates it.
    noise_floor
        Lower bound of the noise (mm), e.g. the mesh error.
    ell
        Smoothing length along the interface (arc length; distance between a
        surface's nodes), mm.
    alpha
        Level of the bands and of the global test.
    n_noise
        Noise replicates per draw for the p-values and the simultaneous bands.
    noise_lag
        Arc length (mm) between the nodes whose second differences estimate the noise
        when ``sigma`` is None (:func:`estimate_noise`; the lag in nodes is this over the
        median node spacing, at least 1): 0 for white noise, a few pixel sizes for
        interfaces traced from images (used by the ``gaussian`` noise model).
    noise_model
        ``gaussian`` (i.i.d. normal noise of sd ``sigma`` per node) or ``bootstrap``
        (resampled leave-one-out rough residuals, :func:`noise_pool`; needs
        ``ell > 0``); see the module docstring.
    segmentation_sigma
        Positional uncertainty of the observed interfaces from their segmentation (mm;
        raw scans, :meth:`bayescalib.io.observation_store.StoredObservations.segmentation_sigma`):
        a lower bound of an estimated ``sigma`` (the source says when it binds);
        reported beside a given one. None: none (masks, coordinates, synthetic data).
    rng
        Random generator (replicates).
    """
    if noise_model not in NOISE_MODELS:
        raise ValueError(f"noise_model {noise_model!r} unknown; choose from {NOISE_MODELS}")
    if noise_model == "bootstrap" and not ell > 0:
        raise ValueError("the bootstrap noise model needs a smoothing length ell > 0 (its "
                         "smooth part is what it takes out of the residual)")
    n_snap = len(observed)
    if len(draws) < 2:
        raise ValueError(f"the predictive check needs at least 2 posterior draws, got {len(draws)}")
    if any(len(d) != n_snap for d in draws):
        raise ValueError("every posterior draw needs one predicted interface per snapshot")
    labels = list(labels) if labels is not None else [f"snapshot {i}" for i in range(n_snap)]
    per = []
    for i in range(n_snap):
        pts = np.stack([np.asarray(d[i].points) for d in draws])
        mean = Interface(pts.mean(axis=0), draws[0][i].cells, name="mean prediction")
        obs_pts = np.asarray(getattr(observed[i], "points", observed[i]), dtype=float)
        y, o = offsets(obs_pts, mean, [d[i] for d in draws])
        per.append((obs_pts, y, o))
    smooth_ops = [smoother(node_coordinates(obs_pts), ell) for obs_pts, _, _ in per]
    pool = pool_info = None
    data_sigma: float | None = None
    if noise_model == "bootstrap":
        pool = noise_pool([y - o.mean(axis=0) for _, y, o in per],
                          [node_coordinates(p) for p, _, _ in per], ell)
        rms = float(np.sqrt(np.mean(pool**2)))
        if sigma is None:
            sig, source = _estimated_sigma(rms, noise_floor, segmentation_sigma)
            data_sigma = rms
        else:
            sig, source = float(max(sigma, noise_floor)), "given"
        # (a residual without a rough part, e.g. noise-free data: Gaussian at the floor)
        pool = pool * (sig / rms) if rms > 0 else rng.standard_normal(pool.size) * sig
        pool_info = {"n": int(pool.size), "rms_mm": float(np.sqrt(np.mean(pool**2))),
                     "kurtosis": float(np.mean(pool**4) / np.mean(pool**2) ** 2)}
    elif sigma is None:
        ests = [estimate_noise(y - o.mean(axis=0), lag=_lag_nodes(obs_pts, noise_lag))
                if obs_pts.shape[1] == 2 else estimate_surface_noise(y - o.mean(axis=0), obs_pts)
                for obs_pts, y, o in per]
        data_sigma = float(np.median(ests))
        sig, source = _estimated_sigma(data_sigma, noise_floor, segmentation_sigma)
    else:
        sig, source = float(max(sigma, noise_floor)), "given"

    K = len(draws)
    snaps: list[SnapshotCheck] = []
    reps_chi2 = np.zeros(K * n_noise)
    reps_max = np.zeros(K * n_noise)
    reps_max_s = np.zeros(K * n_noise)
    obs_chi2 = obs_max = obs_max_s = 0.0
    for i, (obs_pts, y, o) in enumerate(per):
        s = arc_length(obs_pts) if obs_pts.shape[1] == 2 else None
        S = smooth_ops[i]
        mu = o.mean(axis=0)
        v = o.var(axis=0, ddof=1) + sig**2
        os_ = o @ S.T
        mu_s = os_.mean(axis=0)
        v_s = os_.var(axis=0, ddof=1) + sig**2 * np.einsum("ij,ij->i", S, S)
        snap = SnapshotCheck(labels[i], s, obs_pts, y, mu, v, S @ y, mu_s, v_s)
        snaps.append(snap)
        obs_chi2 += float(np.sum(snap.z**2))
        obs_max = max(obs_max, float(np.max(np.abs(snap.z))))
        obs_max_s = max(obs_max_s, float(np.max(np.abs(snap.z_s))))
        if pool is None:
            noise = sig * rng.standard_normal((K, n_noise, len(y)))
        else:
            noise = resample_noise(pool, (K, n_noise, len(y)), rng)
        rep = o[:, None, :] + noise  # (K, L, n)
        z = (rep - mu) / np.sqrt(v)
        z_s = (rep @ S.T - mu_s) / np.sqrt(v_s)
        reps_chi2 += np.sum(z**2, axis=2).ravel()
        reps_max = np.maximum(reps_max, np.max(np.abs(z), axis=2).ravel())
        reps_max_s = np.maximum(reps_max_s, np.max(np.abs(z_s), axis=2).ravel())
    n_rep = K * n_noise
    p = {
        "chi2": float((np.sum(reps_chi2 >= obs_chi2) + 1) / (n_rep + 1)),
        "max_abs": float((np.sum(reps_max >= obs_max) + 1) / (n_rep + 1)),
        "max_abs_smooth": float((np.sum(reps_max_s >= obs_max_s) + 1) / (n_rep + 1)),
    }
    c_pw = float(ndtri(1.0 - alpha / 2.0))
    c_sim = float(np.quantile(reps_max, 1.0 - alpha))
    c_s = float(np.quantile(reps_max_s, 1.0 - alpha))
    adequate = min(p.values()) >= alpha / 3.0
    located = []
    bands = [np.abs(snap.z_s) > c_s for snap in snaps]
    core_cut = CORE_SHARE * max((float(np.max(np.abs(sn.y_s - sn.mu_s)[b]))
                                 for sn, b in zip(snaps, bands, strict=True) if b.any()),
                                default=0.0)
    for snap, band in zip(snaps, bands, strict=True):
        r_s = np.abs(snap.y_s - snap.mu_s)
        if snap.s is None:
            located += _located_on_surface(snap, band, r_s >= core_cut)
            continue
        for a, b in intervals(band, snap.s):
            seg = slice(a, b + 1)
            k = a + int(np.argmax(np.abs(snap.z_s[seg])))
            core = [(a + c0, a + c1) for c0, c1 in
                    intervals(r_s[seg] >= core_cut, snap.s[seg], min_gap=0)]
            located.append({
                "snapshot": snap.label, "nodes": [a, b],
                "arc_length_mm": [float(snap.s[a]), float(snap.s[b])],
                "x_mm": [float(snap.xy[seg, 0].min()), float(snap.xy[seg, 0].max())],
                "y_mm": [float(snap.xy[seg, 1].min()), float(snap.xy[seg, 1].max())],
                "peak_z": float(snap.z_s[k]),
                "peak_residual_mm": float(snap.y_s[k] - snap.mu_s[k]),
                "direction": "observed outside the prediction (into the fluid)"
                if snap.z_s[k] > 0 else "observed inside the prediction",
                "core_nodes": [[c0, c1] for c0, c1 in core],
                "core_arc_length_mm": [[float(snap.s[c0]), float(snap.s[c1])]
                                       for c0, c1 in core],
            })
    allr = np.concatenate([sn.y - sn.mu for sn in snaps])
    allz = np.concatenate([sn.z for sn in snaps])
    # drawn after the replicates, so the p-values do not depend on it
    spread = rms_spread([y for _, y, _ in per], [o for _, _, o in per], rng)
    return PredictiveCheck(
        snapshots=snaps, sigma=sig, sigma_source=source, alpha=alpha, c_pointwise=c_pw,
        c_simultaneous=c_sim, c_smooth=c_s,
        statistics={"chi2": obs_chi2, "max_abs": obs_max, "max_abs_smooth": obs_max_s,
                    "n_nodes": int(allr.size)},
        p_values=p, adequate=bool(adequate), located=located,
        rms=float(np.sqrt(np.mean(allr**2))),
        coverage=float(np.mean(np.abs(allz) <= c_pw)), noise_lag=float(noise_lag),
        noise_model=noise_model, noise_pool=pool_info, rms_spread=spread,
        sigma_data=data_sigma if segmentation_sigma is not None else None,
        sigma_segmentation=None if segmentation_sigma is None else float(segmentation_sigma),
    )


def colony_place(point: np.ndarray, nodes: np.ndarray) -> str:
    """Where on an observed colony surface a point lies, in words: its height as a
    share of the colony's (``"near the top"`` above 3/4, else the lower or upper half of
    the flank) and, on the flank, its side as seen from the footprint's centre
    (``upstream``: towards -x, against the flow; ``downstream``; the ``side at +z`` or
    ``-z``, across the channel).

    Parameters
    ----------
    point
        (3,) mm (x along the flow, y up, z across).
    nodes
        (n, 3) the observed surface's nodes, mm.
    """
    p = np.asarray(point, dtype=float)
    pts = np.asarray(nodes, dtype=float)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    mid = 0.5 * (lo + hi)
    f = (p[1] - lo[1]) / ((hi[1] - lo[1]) or 1.0)
    if f > 0.75:
        return "near the top"
    dx = (p[0] - mid[0]) / ((hi[0] - lo[0]) or 1.0)
    dz = (p[2] - mid[2]) / ((hi[2] - lo[2]) or 1.0)
    side = (("upstream" if dx < 0 else "downstream") if abs(dx) >= abs(dz) else
            ("side at +z" if dz > 0 else "side at -z"))
    return f"on the {side} flank, {'upper' if f > 0.4 else 'lower'} part"


def _located_on_surface(snap: SnapshotCheck, band: np.ndarray,
                        core: np.ndarray) -> list[dict]:
    """The located regions of one surface snapshot (:func:`surface_regions` of the
    nodes outside the smoothed residual's simultaneous band), with their cores (the
    region's nodes in ``core``: at least :data:`CORE_SHARE` of the largest smoothed
    residual)."""
    out = []
    for nodes in surface_regions(band, snap.xy):
        k = int(nodes[np.argmax(np.abs(snap.z_s[nodes]))])
        sub = snap.xy[nodes]
        inner = nodes[core[nodes]]
        out.append({
            "snapshot": snap.label, "node_indices": nodes.tolist(), "n_nodes": int(nodes.size),
            "x_mm": [float(sub[:, 0].min()), float(sub[:, 0].max())],
            "y_mm": [float(sub[:, 1].min()), float(sub[:, 1].max())],
            "z_mm": [float(sub[:, 2].min()), float(sub[:, 2].max())],
            "peak_mm": [float(c) for c in snap.xy[k]],
            "where": colony_place(snap.xy[k], snap.xy),
            "peak_z": float(snap.z_s[k]),
            "peak_residual_mm": float(snap.y_s[k] - snap.mu_s[k]),
            "direction": "observed outside the prediction (into the fluid)"
            if snap.z_s[k] > 0 else "observed inside the prediction",
            "core_node_indices": inner.tolist(),
            "core_where": colony_place(snap.xy[inner].mean(axis=0), snap.xy)
            if inner.size else None,
        })
    return out


def _estimated_sigma(data: float, noise_floor: float,
                     segmentation: float | None) -> tuple[float, str]:
    """The estimated noise sd (mm) and its source: the data-based estimate, floored at
    ``noise_floor`` and at the segmentation's positional uncertainty (when known)."""
    if segmentation is not None and segmentation > max(data, noise_floor):
        return float(segmentation), "segmentation (lower bound)"
    return float(max(data, noise_floor)), "estimated"
