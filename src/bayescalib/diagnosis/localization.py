"""How well the diagnosis's located mismatch matches a known hidden effect.

Used where the truth is known (the concealed-effect benchmark,
``benchmarks/concealed.py``): the data hide an effect that the base model (the
calibrated parameters theta, e.g. E and nu) does not have, and the diagnosis locates
where the observed interface leaves the predictive band
(:mod:`bayescalib.diagnosis.stage`, ``check.located``). The score is the Jaccard index
(intersection over union, IoU) over the observed nodes between the located nodes and
an *effect region*:

* **raw**: the nodes where the hidden effect moves the interface by at least half its
  maximum on that snapshot (none on a snapshot where the effect is only rounding,
  :data:`NEGLIGIBLE`). The effect at node j of snapshot s is the signed normal
  offset ``y_sj`` of the noise-free true interface from the base model solved at the
  true theta (:func:`bayescalib.diagnosis.residuals.offsets`).
* **unabsorbable**: the same for the effect's part that the base parameters cannot
  mimic. With ``J`` (n, p) the finite-difference Jacobian of the base model's offsets
  in theta at the truth (all snapshots stacked), ``u = y - J (J^T J)^-1 J^T y`` (least
  squares); the region is ``|u_j| >= max|u| / 2`` over all snapshots. This is where a
  calibrated base model can still show the effect, to first order (the residual of a
  Gauss-Newton re-fit, cf. the linearized attribution in
  :mod:`bayescalib.diagnosis.attribution`).

The threshold "half the maximum" is the half-maximum rule that also defines the
located *cores* (the located nodes whose smoothed residual is at least half its
largest value), so the core IoU compares like with like.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["NEGLIGIBLE", "EffectRegions", "effect_regions", "located_overlap",
           "nearest_nodes"]

#: a snapshot whose largest effect is below this fraction of the largest over all
#: snapshots has no raw region: rounding, not an effect (a flow-driven effect at zero
#: load differs from the base model by ~1e-15 um, whose half maximum would mark
#: arbitrary nodes)
NEGLIGIBLE = 1.0e-6


@dataclass
class EffectRegions:
    """Per observed snapshot, the nodes where a hidden effect shows.

    Attributes
    ----------
    raw
        One boolean array (n_s,) per snapshot: the effect's half-maximum region.
    unabsorbable
        One boolean array (n_s,) per snapshot: its unabsorbable part's region.
    unabsorbable_fraction
        ``||u|| / ||y||`` over the snapshots scored (None for no effect at all).
    excluded
        Snapshot label -> why it is not scored (empty: every snapshot is).
    """

    raw: list[np.ndarray | None]
    unabsorbable: list[np.ndarray | None]
    unabsorbable_fraction: float | None
    excluded: dict[str, str] = field(default_factory=dict)


def nearest_nodes(points: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Index of the nearest of ``nodes`` (m, 2) for each of ``points`` (n, 2), mm.

    Returns
    -------
    ndarray, shape (n,)
        Integer indices into ``nodes``.
    """
    points = np.asarray(points, dtype=float)
    nodes = np.asarray(nodes, dtype=float)
    d2 = np.sum((points[:, None, :] - nodes[None, :, :]) ** 2, axis=2)
    return np.argmin(d2, axis=1)


def _curves(run) -> list[np.ndarray]:
    """The deformed interface (n, 2), mm, per loading of a run (one for a single solve)."""
    return [ld.current for ld in run.loadings] or [run.interface_current]


def _per_snapshot(fm: Mapping[str, Any], points: Sequence[Mapping[str, float]],
                  stems: Sequence[Path]) -> tuple[list[list[np.ndarray | None]], list, list]:
    """Solve the base model at ``points``; where a series of loadings fails as a whole,
    solve each of its loadings alone, so that the loadings that converge are kept.

    Returns the curves (one list per point, ``None`` per loading that failed), the
    segments per point (``None`` for a point with no loading solved) and the reason per
    point and loading (``""`` where it converged).
    """
    from bayescalib.models.forward import loading_factors, loading_labels, solve_points

    # not with_suffix: a target's name has dots (base_at_truth_fd_material.E)
    runs = solve_points(fm, points, [Path(f"{s}.h5") for s in stems])
    loadings = fm.get("loadings") or {}
    factors = loading_factors(fm)
    n_snap = max(1, len(factors))
    curves = [_curves(r) if r.ok else [None] * n_snap for r in runs]
    segments = [r.segments if r.ok else None for r in runs]
    reasons = [[""] * n_snap if r.ok else [r.reason] * n_snap for r in runs]
    redo = [k for k, r in enumerate(runs) if not r.ok and n_snap > 1]
    if redo:
        labels = loading_labels(factors)
        jobs = [(k, s) for k in redo for s in range(n_snap)]
        # a loading alone is the one-loading series of that factor (the same solve path)
        alone = [{**fm, "loadings": {**loadings, "factors": [factors[s]]}} for _, s in jobs]
        single = [solve_points(f, [points[k]], [Path(f"{stems[k]}_{labels[s]}.h5")])[0]
                  for f, (k, s) in zip(alone, jobs, strict=True)]
        for (k, s), r in zip(jobs, single, strict=True):
            curves[k][s] = np.asarray(r.interface_current) if r.ok else None
            reasons[k][s] = "" if r.ok else r.reason
            if r.ok and segments[k] is None:
                segments[k] = r.segments
    return curves, segments, reasons


def effect_regions(fm: Mapping[str, Any], truth: Mapping[str, float],
                   bounds: Mapping[str, tuple[float, float]],
                   truth_curves: Sequence[np.ndarray], out_dir: str | Path, *,
                   fd_step: float = 0.01,
                   observed: Sequence[np.ndarray] | None = None) -> EffectRegions | None:
    """The raw and unabsorbable regions of a hidden effect (see the module docstring).

    The base model is solved at the truth and at one finite-difference step per
    calibrated parameter. Where a series of loadings fails as a whole (e.g. the base
    model inverts elements at the largest loads, where the data's hidden stiffening
    does not), each of its loadings is solved alone: a snapshot where the base model at
    the truth has no solution has no effect region (the effect is not defined there); it
    is left out of the scores and named in :attr:`EffectRegions.excluded` with the
    solver's reason. The Jacobian uses the steps that solved on every snapshot scored.

    Parameters
    ----------
    fm
        Validated ``forward_model`` section of the study (``loadings`` included): the
        base model, without the hidden effect.
    truth
        The true values of the calibrated parameters, by target.
    bounds
        ``(lo, hi)`` of each calibrated parameter, by target: the finite-difference step
        is ``fd_step * (hi - lo)``, taken backwards where forwards leaves the box.
    truth_curves
        The noise-free true interface per snapshot, (n_s, 2) mm each, in the order of
        the loadings (the hidden effect included; a hidden misregistration applied).
    out_dir
        Folder of the run records: ``base_at_truth.h5`` and
        ``base_at_truth_fd_<target>.h5`` (and ``..._<loading label>.h5`` for loadings
        solved alone); records solved at the same values are reused.
    fd_step
        Relative finite-difference step.
    observed
        Observed nodes per snapshot, (m_s, 2) mm, where they are not the truth's
        (observations from images): each takes the region value of its nearest true
        node. ``None``: the regions are on the truth's nodes.

    Returns
    -------
    EffectRegions or None
        None where the base model at the truth could not be solved at any loading.
    """
    from bayescalib.diagnosis.residuals import offsets
    from bayescalib.geometry.interface import Interface
    from bayescalib.models.forward import loading_factors, loading_labels

    out_dir = Path(out_dir)
    steps: dict[str, float] = {}
    pts: list[dict[str, float]] = [dict(truth)]
    for t, (lo, hi) in bounds.items():
        h = fd_step * (hi - lo)
        h = -h if truth[t] + h > hi else h
        steps[t] = h
        pts.append({**truth, t: truth[t] + h})
    curves, segments, reasons = _per_snapshot(
        fm, pts, [out_dir / "base_at_truth"] + [out_dir / f"base_at_truth_fd_{t}"
                                                 for t in steps])
    gts = [np.asarray(g, dtype=float) for g in truth_curves]
    if len(gts) != len(curves[0]):
        raise ValueError(f"effect_regions: {len(gts)} true interfaces for "
                         f"{len(curves[0])} loadings of the forward model")
    scored = [s for s, c in enumerate(curves[0]) if c is not None]
    if not scored:
        return None
    factors = loading_factors(fm)
    labels = loading_labels(factors) if len(factors) > 1 else ["nominal"]
    excluded = {labels[s]: reasons[0][s] for s in range(len(gts)) if s not in scored}
    fd = [(k, h) for k, h in enumerate(steps.values(), start=1)
          if all(curves[k][s] is not None for s in scored)]
    ys, cols = [], []
    for s in scored:
        y, o = offsets(gts[s], Interface(curves[0][s], segments[0]),
                       [Interface(curves[k][s], segments[k]) for k, _ in fd])
        ys.append(y)
        cols.append(o / np.array([h for _, h in fd])[:, None] if fd else o)
    peak = max(float(np.max(np.abs(y))) for y in ys)
    raw_s = [np.abs(y) >= 0.5 * np.max(np.abs(y)) if np.max(np.abs(y)) > NEGLIGIBLE * peak
             else np.zeros(len(y), dtype=bool) for y in ys]
    y_all = np.concatenate(ys)
    J = np.concatenate(cols, axis=1).T  # (n, p)
    u = y_all - J @ np.linalg.lstsq(J, y_all, rcond=None)[0] if J.size else y_all
    cut = 0.5 * np.max(np.abs(u))
    splits = np.cumsum([len(y) for y in ys])[:-1]
    unabs_s = [np.abs(part) >= cut if cut > 0 else np.zeros(len(part), dtype=bool)
               for part in np.split(u, splits)]
    if observed is not None:
        near = [nearest_nodes(observed[s], gts[s]) for s in scored]
        raw_s = [r[i] for r, i in zip(raw_s, near, strict=True)]
        unabs_s = [r[i] for r, i in zip(unabs_s, near, strict=True)]
    raw: list[np.ndarray | None] = [None] * len(gts)
    unabs: list[np.ndarray | None] = [None] * len(gts)
    for s, r, ua in zip(scored, raw_s, unabs_s, strict=True):
        raw[s], unabs[s] = r, ua
    return EffectRegions(
        raw=raw, unabsorbable=unabs,
        unabsorbable_fraction=float(np.linalg.norm(u) / np.linalg.norm(y_all))
        if np.linalg.norm(y_all) > 0 else None,
        excluded=excluded)


def located_overlap(located: Sequence[Mapping[str, Any]],
                    regions: Sequence[np.ndarray | None] | None, labels: Sequence[str],
                    core: bool = False) -> float | None:
    """IoU of the located nodes against an effect region, over the snapshots scored.

    Parameters
    ----------
    located
        The diagnosis's ``check.located`` entries: ``snapshot`` (label), ``nodes``
        (first and last located node, inclusive) and, where recorded, ``core_nodes``
        (list of inclusive node ranges); on a 3D surface ``node_indices`` and
        ``core_node_indices``.
    regions
        One boolean array (n_s,) per snapshot (as ``labels``), e.g.
        :attr:`EffectRegions.raw`; ``None`` for a snapshot left out of the score (its
        located nodes do not count).
    labels
        Snapshot labels, in the order of ``regions``.
    core
        Score the located cores instead of the whole located intervals.

    Returns
    -------
    float or None
        The IoU in [0, 1]; None without regions, where the union is empty, or for
        ``core`` where the diagnosis recorded no cores.
    """
    if regions is None or all(r is None for r in regions):
        return None
    located_nodes = [None if r is None else np.zeros(len(r), dtype=bool) for r in regions]
    for loc in located:
        if core and "core_nodes" not in loc and "core_node_indices" not in loc:
            return None
        hit = located_nodes[list(labels).index(loc["snapshot"])]
        if hit is None:
            continue
        if "node_indices" in loc:  # a region of a 3D surface
            hit[loc["core_node_indices"] if core else loc["node_indices"]] = True
            continue
        for a, b in loc["core_nodes"] if core else [loc["nodes"]]:
            hit[a:b + 1] = True
    loc_all = np.concatenate([m for m in located_nodes if m is not None])
    reg_all = np.concatenate([r for r in regions if r is not None])
    union = np.sum(loc_all | reg_all)
    return float(np.sum(loc_all & reg_all) / union) if union else None
