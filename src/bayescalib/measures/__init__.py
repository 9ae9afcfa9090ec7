"""Discrepancy measures D between a model and an observed interface (paper Sec. 2.4).

Three measures, each returning a :class:`MeasureResult` with the distance
vector, the scalar D entering the likelihood (eq:loglik) and the number of
measurements n used there:

``euclidean`` (eq:eucliddist)
    Signed distances ``d_i`` along preset directions from measurement points on
    the *observed* interface to the model interface; ``D = ||d||_2``,
    ``n = n_mp``. A point's line ``p_i + t u_i`` is intersected with the model
    cells in both directions and the hit nearest to ``p_i`` is used; ``d_i = t``
    is positive when the model lies on the side ``u_i`` points to (with the
    default directions, the observed normal: into the fluid).

    *Default points* (the paper's recommendation: where the displacement is
    significant, directions normal to the observed interface). Candidates
    are the cell centres of the observed interface with their unit normals.
    With a ``reference`` (undeformed) interface, each candidate's displacement
    is its unsigned closest-point distance to the reference. Only candidates
    displaced by at least 10 % of the maximum displacement are eligible (all,
    if fewer than n_points are); they are taken greedily in order of
    decreasing displacement, skipping any closer than ``s = 0.5 * L / n_points``
    (2D, L the length of the eligible cells) or ``0.5 * sqrt(A / n_points)``
    (3D, A their area) to an already chosen point, so the points spread over
    the strongly displaced region instead of clustering at the maximum. Without a reference the points are spread
    evenly: at arc-length fractions ``(k + 1/2) / n_points`` for ordered 2D
    curves, else by farthest-point sampling of the centres.

    *Missed rays*: when a line does not hit the model interface (e.g. a
    model far too small), the distance is a finite penalty, by default the
    diagonal of the bounding box of both interfaces, which is at least as
    large as any distance a hit could give (``on_miss="penalty"``). The
    log-likelihood therefore stays finite and decreases with the miss;
    ``on_miss="raise"`` raises :class:`MeasureError` instead.

``cpp`` (eq:cppdist)
    For every model node the distance to its closest point on the observed
    cells (projection onto segments/triangles), signed by the observed normal;
    ``D = ||d||_2``, ``n = n_in`` (number of model interface nodes).

``rkhs`` (eq:inner_prod_rkhs, eq:surfcurrontriang)
    The surface-current norm of :mod:`bayescalib.measures.currents` after resampling both
    interfaces to ``spacing`` (default ``sigma_w / 4``). D is one scalar; the
    distance vector is ``[D]`` and ``n = 1``: the measure reduces the whole
    interface to a single number, which is the one "measurement" whose
    Gaussian model eq:staticlikeli describes (n only shifts log L by a
    constant, so it affects the evidence, never the posterior).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.geometry.interface import Interface
from bayescalib.geometry.projection import closest_points, ray_distances

__all__ = [
    "MEASURES",
    "MeasureError",
    "MeasureOptionError",
    "MeasureResult",
    "closest_point",
    "compute",
    "default_measurement_points",
    "euclidean",
    "noise_floor",
    "rkhs",
]


class MeasureError(ValueError):
    """A measure cannot be evaluated for these interfaces (e.g. a missed ray with
    ``on_miss="raise"``, interfaces of different dimension)."""


class MeasureOptionError(MeasureError):
    """A measure is called with an unknown name or invalid options (a user error)."""


@dataclass
class MeasureResult:
    """Result of a discrepancy measure.

    Attributes
    ----------
    distances : ndarray, shape (k,)
        Signed distances (mm) for ``euclidean`` (k = n_mp) and ``cpp``
        (k = model nodes); ``[D]`` for ``rkhs``.
    D : float
        The discrepancy entering eq:loglik.
    n : int
        Number of measurements for eq:loglik.
    """

    distances: np.ndarray
    D: float
    n: int


def _validate_pair(model: Interface, obs: Interface) -> None:
    if not isinstance(model, Interface) or not isinstance(obs, Interface):
        raise MeasureError("model and observation must be Interface objects")
    if model.dim != obs.dim:
        raise MeasureError(f"cannot compare a {model.dim}D model interface with a {obs.dim}D observation")


def _farthest_point_sampling(x: np.ndarray, k: int) -> np.ndarray:
    start = int(np.argmin(np.linalg.norm(x - x.mean(axis=0), axis=1)))
    chosen = [start]
    dmin = np.linalg.norm(x - x[start], axis=1)
    for _ in range(1, k):
        j = int(np.argmax(dmin))
        chosen.append(j)
        dmin = np.minimum(dmin, np.linalg.norm(x - x[j], axis=1))
    return np.array(chosen)


def default_measurement_points(
    obs: Interface, n_points: int = 10, reference: Interface | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Measurement points and directions on the observed interface (rule: module docstring).

    Parameters
    ----------
    obs : Interface
        Observed interface.
    n_points : int
        Number of points n_mp (>= 1, at most the number of observed cells).
    reference : Interface, optional
        Undeformed interface; when given points go where the displacement is large.

    Returns
    -------
    points : ndarray, shape (n_points, d)
    directions : ndarray, shape (n_points, d)
        Unit observed normals at the points.
    """
    n_points = int(n_points)
    if n_points < 1:
        raise MeasureOptionError(f"n_points must be >= 1, got {n_points}")
    centres, normals = obs.centres, obs.normals
    if n_points > centres.shape[0] and (reference is not None or not obs.is_chain()):
        raise MeasureOptionError(
            f"n_points = {n_points} exceeds the {centres.shape[0]} cells of the observed interface"
        )
    if reference is not None:
        if reference.dim != obs.dim:
            raise MeasureError("reference and observed interface differ in dimension")
        disp = np.abs(closest_points(centres, reference)[0])
        significant = disp >= SIGNIFICANT * disp.max()
        if np.count_nonzero(significant) < n_points:
            significant = np.ones_like(significant)
        size = float(obs.measures[significant].sum())
        sep = 0.5 * size / n_points if obs.dim == 2 else 0.5 * math.sqrt(size / n_points)
        order = np.argsort(-disp, kind="stable")
        chosen: list[int] = []
        for j in order[significant[order]]:
            if all(np.linalg.norm(centres[j] - centres[c]) >= sep for c in chosen):
                chosen.append(int(j))
                if len(chosen) == n_points:
                    break
        if len(chosen) < n_points:  # separation too strict: fill by displacement
            rest = [int(j) for j in order if int(j) not in chosen]
            chosen += rest[: n_points - len(chosen)]
        idx = np.array(chosen)
        return centres[idx].copy(), normals[idx].copy()
    if obs.dim == 2 and obs.is_chain():
        s = obs.arc_length()
        seg_start = s[obs.cells[:, 0]]
        targets = (np.arange(n_points) + 0.5) / n_points * obs.total_measure
        seg = np.clip(np.searchsorted(seg_start, targets, side="right") - 1, 0, obs.n_cells - 1)
        p = obs.points[obs.cells[seg]]
        frac = np.clip((targets - seg_start[seg]) / obs.measures[seg], 0.0, 1.0)
        pts = p[:, 0] + frac[:, None] * (p[:, 1] - p[:, 0])
        return pts, normals[seg].copy()
    idx = _farthest_point_sampling(centres, n_points)
    return centres[idx].copy(), normals[idx].copy()


def euclidean(
    model: Interface,
    obs: Interface,
    points: np.ndarray | None = None,
    directions: np.ndarray | None = None,
    n_points: int = 10,
    reference: Interface | None = None,
    on_miss: str = "penalty",
    miss_penalty: float | None = None,
) -> MeasureResult:
    """Euclidean distance at measurement points along preset directions (eq:eucliddist).

    Parameters
    ----------
    model, obs : Interface
        Model and observed interfaces (same dimension), mm.
    points : ndarray, shape (k, d), or str/Path, optional
        Measurement points (on or near the observed interface), or a CSV file
        read by :func:`bayescalib.io.observations.read_points` (its optional
        direction columns are used when ``directions`` is None). Default: see
        :func:`default_measurement_points`.
    directions : ndarray, shape (k, d), optional
        Measurement directions (normalized here). Default: the observed
        normal at the closest point of each point.
    n_points : int
        Number of default points (ignored when ``points`` is given).
    reference : Interface, optional
        Undeformed interface for the default point rule.
    on_miss : {"penalty", "raise"}
        What to do when a line misses the model interface.
    miss_penalty : float, optional
        Distance used for a miss; default the bounding-box diagonal of both
        interfaces.

    Returns
    -------
    MeasureResult
        ``distances`` (k,), ``D = ||d||_2``, ``n = k``.
    """
    _validate_pair(model, obs)
    d = model.dim
    if isinstance(points, (str, Path)):
        from bayescalib.io.observations import read_points

        points, file_dirs = read_points(points)
        if directions is None:
            directions = file_dirs
    if points is None:
        if directions is not None:
            raise MeasureOptionError("directions given without points")
        pts, dirs = default_measurement_points(obs, n_points, reference)
    else:
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != d or pts.shape[0] < 1:
            raise MeasureOptionError(f"measurement points must have shape (k, {d}), got {pts.shape}")
        if not np.isfinite(pts).all():
            raise MeasureOptionError("measurement points contain NaN/inf")
        if directions is None:
            _, _, cell = closest_points(pts, obs)
            dirs = obs.normals[cell]
        else:
            dirs = np.asarray(directions, dtype=float)
            if dirs.shape != pts.shape:
                raise MeasureOptionError(
                    f"directions must have the shape of points {pts.shape}, got {dirs.shape}"
                )
    norm = np.linalg.norm(dirs, axis=1)
    if not np.all(np.isfinite(norm)) or np.any(norm <= 0):
        raise MeasureOptionError("measurement directions must be finite and non-zero")
    dirs = dirs / norm[:, None]
    t = ray_distances(pts, dirs, model)
    miss = ~np.isfinite(t)
    if miss.any():
        if on_miss == "raise":
            raise MeasureError(
                f"{int(miss.sum())} of {t.size} measurement line(s) miss the model interface "
                f"(first: point {pts[np.flatnonzero(miss)[0]].tolist()})"
            )
        if on_miss != "penalty":
            raise MeasureOptionError(f"on_miss must be 'penalty' or 'raise', got {on_miss!r}")
        if miss_penalty is None:
            allp = np.vstack([model.points, obs.points, pts])
            miss_penalty = float(np.linalg.norm(np.ptp(allp, axis=0)))
        t = np.where(miss, float(miss_penalty), t)
    return MeasureResult(distances=t, D=float(np.linalg.norm(t)), n=int(t.size))


def closest_point(model: Interface, obs: Interface) -> MeasureResult:
    """Closest point projection distance of every model node (eq:cppdist).

    Returns
    -------
    MeasureResult
        ``distances`` (n_in,) signed by the observed normal, ``D = ||d||_2``,
        ``n = n_in`` (number of model interface nodes).
    """
    _validate_pair(model, obs)
    signed, _, _ = closest_points(model.points, obs)
    return MeasureResult(distances=signed, D=float(np.linalg.norm(signed)), n=int(signed.size))


def rkhs(
    model: Interface,
    obs: Interface,
    sigma_w: float = 0.005,
    spacing: float | None = None,
    device: str | None = None,
    chunk: int | None = None,
    backend: str = "auto",
    dtype: str = "float64",
    truncate: float | None = None,
    threads: int | None = None,
    max_pairs: float | None = None,
    residual: str = "scalar",
    field_band: float = 8.0,
    field_spacing: float = 0.75,
) -> MeasureResult:
    """RKHS surface-current norm (eq:inner_prod_rkhs, eq:surfcurrontriang).

    Parameters
    ----------
    model, obs : Interface
    sigma_w : float
        Kernel width sigma_W in mm (paper: 0.005).
    spacing : float, optional
        Resampling spacing in mm; None -> ``sigma_w / 4``; ``math.inf`` -> none.
    device : str, optional
        torch device (None: CUDA when available, else CPU).
    chunk : int, optional
        Maximum kernel entries per block (memory bound).
    backend : {"auto", "numpy", "torch"}
    dtype : {"float64", "float32"}
        torch precision.
    truncate : float, optional
        Kernel truncation radius in units of sigma_w (default: exact to double
        precision, see :func:`bayescalib.measures.currents.pair_sum`).
    threads : int, optional
        torch CPU threads during the computation (None: 1; 0: keep the global
        torch setting).
    max_pairs : float, optional
        Most kernel pairs to evaluate (None: :data:`bayescalib.measures.currents.DEFAULT_MAX_PAIRS`);
        above it the measure is refused before any work.

    residual : {"scalar", "field", "auto"}
        The distance vector: ``[D]`` (``auto``: a study resolves it by its
        ``surrogate.target``; alone, the scalar), or the smoothed currents' difference on a band
        of grid nodes around the observed interface
        (:func:`bayescalib.measures.currents.field_residual`), whose norm is D; the
        residual an emulator of the model's outputs learns (``surrogate.target:
        outputs``). D and the likelihood are the same either way.
    field_band, field_spacing : float
        The band's half-width and the grid spacing, in units of sigma_w.

    Returns
    -------
    MeasureResult
        ``distances`` (``[D]`` or the field residual), ``D``, ``n = 1``.
    """
    from bayescalib.measures import currents as _rk

    if residual not in ("auto", "scalar", "field"):
        raise MeasureOptionError(f"residual must be 'scalar', 'field' or 'auto', got {residual!r}")

    _validate_pair(model, obs)
    if not (isinstance(sigma_w, (int, float)) and np.isfinite(sigma_w) and sigma_w > 0):
        raise MeasureOptionError(f"sigma_w must be a positive number in mm, got {sigma_w!r}")
    try:
        D = _rk.rkhs_distance(
            model,
            obs,
            float(sigma_w),
            spacing=spacing,
            backend=backend,
            device=device,
            dtype=dtype,
            chunk=_rk.DEFAULT_CHUNK if chunk is None else int(chunk),
            truncate=_rk.DEFAULT_TRUNCATE if truncate is None else truncate,
            threads=_rk.DEFAULT_THREADS if threads is None else (int(threads) or None),
            max_pairs=_rk.DEFAULT_MAX_PAIRS if max_pairs is None else float(max_pairs),
        )
    except ValueError as exc:
        raise MeasureOptionError(str(exc)) from None
    if residual == "field":
        r = _rk.field_residual(model, obs, float(sigma_w), D, spacing=spacing,
                               band=float(field_band), field_spacing=float(field_spacing))
        return MeasureResult(distances=r, D=D, n=1)
    return MeasureResult(distances=np.array([D]), D=D, n=1)


#: displacement fraction of the maximum above which a point counts as "significantly displaced"
SIGNIFICANT = 0.1

#: measure name -> (function, accepted keyword options)
MEASURES: dict[str, tuple[Any, frozenset[str]]] = {
    "euclidean": (
        euclidean,
        frozenset({"points", "directions", "n_points", "reference", "on_miss", "miss_penalty"}),
    ),
    "cpp": (closest_point, frozenset()),
    "rkhs": (
        rkhs,
        frozenset({"sigma_w", "spacing", "device", "chunk", "backend", "dtype", "truncate", "threads",
                   "max_pairs", "residual", "field_band", "field_spacing"}),
    ),
}


def compute(name: str, model: Interface, obs: Interface, **options: Any) -> MeasureResult:
    """Evaluate measure ``name`` in {"euclidean", "cpp", "rkhs"} with its options.

    Options whose value is None are ignored (the measure's default applies), so
    a validated config section can be passed through as is.

    Raises
    ------
    MeasureOptionError
        For an unknown measure name or an option the measure does not accept.
    """
    if name not in MEASURES:
        raise MeasureOptionError(f"unknown measure {name!r}; choose one of {', '.join(MEASURES)}")
    fn, allowed = MEASURES[name]
    opts = {k: v for k, v in options.items() if v is not None}
    bad = sorted(set(opts) - allowed)
    if bad:
        raise MeasureOptionError(
            f"measure {name!r} does not accept option(s) {', '.join(bad)}; "
            f"allowed: {', '.join(sorted(allowed)) or 'none'}"
        )
    return fn(model, obs, **opts)


def noise_floor(name: str, interface: Interface, sigma: float, *, draws: int = 16,
                seed: int = 0, transform: Any = None, **options: Any) -> float:
    """What coordinate noise alone gives measure ``name``: the mean of ``D^2 / n`` between
    ``interface`` and copies of it with Gaussian noise of sd ``sigma`` on every point.

    This is the likelihood's ``sigma_N^2`` (eq:loglik) that matches noise of ``sigma``
    for this measure and this interface: for ``cpp`` and ``euclidean`` about
    ``sigma^2`` (a distance per point), for ``rkhs`` (``n = 1``) the squared norm of the
    noise's surface current, which depends on the kernel width, the interface's size and
    its dimension (a curve's and a surface's differ by orders of magnitude at the same
    ``sigma``), so two studies of one recording with different measures or dimensions
    get the same noise only through this number.

    Parameters
    ----------
    name : str
        Measure name.
    interface : Interface
        The noiseless interface (e.g. a model's at rest), mm.
    sigma : float
        Standard deviation of the coordinate noise, mm.
    draws : int
        Noisy copies averaged over.
    seed : int
        Seed of the noise.
    transform : callable, optional
        Applied to the noiseless and to each noisy interface before the measure, e.g. a
        plane section (the noise of a B-scan cut from a noisy surface).
    **options
        The measure's options (:func:`compute`).

    Returns
    -------
    float
        ``mean(D^2 / n)``, mm^2 (the measure's units squared).
    """
    from bayescalib.io.observations import add_noise

    if draws < 1:
        raise ValueError("noise_floor: draws must be >= 1")
    rng = np.random.default_rng(seed)
    clean = interface if transform is None else transform(interface)
    out = []
    for _ in range(int(draws)):
        noisy = add_noise(interface, float(sigma), rng)
        if transform is not None:
            noisy = transform(noisy)
        res = compute(name, clean, noisy, **options)
        out.append(res.D ** 2 / res.n)
    return float(np.mean(out))
