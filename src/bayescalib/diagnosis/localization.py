"""How well the diagnosis's located mismatch matches a known hidden effect.

Used where the truth is known (the concealed-effect benchmark,
``benchmarks/concealed.py``): the data hide an effect that the base model (the
calibrated parameters theta, e.g. E and nu) does not have, and the diagnosis locates
where the observed interface leaves the predictive band
(:mod:`bayescalib.diagnosis.stage`, ``check.located``). The score is the Jaccard index
(intersection over union, IoU) over the observed nodes between the located nodes and
an *effect region*:

* **raw**: the nodes where the hidden effect moves the interface by at least half its
  maximum on that snapshot. The effect at node j of snapshot s is the signed normal
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

__all__ = ["EffectRegions", "effect_regions", "located_overlap", "nearest_nodes"]


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


def effect_regions(fm: Mapping[str, Any], truth: Mapping[str, float],
                   bounds: Mapping[str, tuple[float, float]],
                   truth_curves: Sequence[np.ndarray], out_dir: str | Path, *,
                   fd_step: float = 0.01,
                   observed: Sequence[np.ndarray] | None = None) -> EffectRegions | None:
    """The raw and unabsorbable regions of a hidden effect (see the module docstring).

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
        ``base_at_truth_fd_<target>.h5``; records solved at the same values are reused.
    fd_step
        Relative finite-difference step.
    observed
        Observed nodes per snapshot, (m_s, 2) mm, where they are not the truth's
        (observations from images): each takes the region value of its nearest true
        node. ``None``: the regions are on the truth's nodes.

    Returns
    -------
    EffectRegions or None
        None where the base model at the truth could not be solved.
    """
    from bayescalib.diagnosis.residuals import offsets
    from bayescalib.geometry.interface import Interface
    from bayescalib.models.forward import solve_points

    out_dir = Path(out_dir)
    steps: dict[str, float] = {}
    pts: list[dict[str, float]] = [dict(truth)]
    for t, (lo, hi) in bounds.items():
        h = fd_step * (hi - lo)
        h = -h if truth[t] + h > hi else h
        steps[t] = h
        pts.append({**truth, t: truth[t] + h})
    runs = solve_points(fm, pts, [out_dir / "base_at_truth.h5"]
                        + [out_dir / f"base_at_truth_fd_{t}.h5" for t in steps])
    if not runs[0].ok:
        return None
    gts = [np.asarray(g, dtype=float) for g in truth_curves]
    bs = _curves(runs[0])
    fd = [(k, h) for k, h in enumerate(steps.values(), start=1) if runs[k].ok]
    ys, cols = [], []
    for s, (g, b) in enumerate(zip(gts, bs, strict=True)):
        y, o = offsets(g, Interface.polyline(b, runs[0].segments),
                       [Interface.polyline(_curves(runs[k])[s], runs[k].segments)
                        for k, _ in fd])
        ys.append(y)
        cols.append(o / np.array([h for _, h in fd])[:, None] if fd else o)
    raw = [np.abs(y) >= 0.5 * np.max(np.abs(y)) if np.max(np.abs(y)) > 0
           else np.zeros(len(y), dtype=bool) for y in ys]
    y_all = np.concatenate(ys)
    J = np.concatenate(cols, axis=1).T  # (n, p)
    u = y_all - J @ np.linalg.lstsq(J, y_all, rcond=None)[0] if J.size else y_all
    cut = 0.5 * np.max(np.abs(u))
    splits = np.cumsum([len(y) for y in ys])[:-1]
    unabs = [np.abs(part) >= cut if cut > 0 else np.zeros(len(part), dtype=bool)
             for part in np.split(u, splits)]
    if observed is not None:
        raw, unabs = ([r[nearest_nodes(o, g)] for r, o, g in zip(regions, observed, gts,
                                                                  strict=True)]
                      for regions in (raw, unabs))
    return EffectRegions(
        raw=raw, unabsorbable=unabs,
        unabsorbable_fraction=float(np.linalg.norm(u) / np.linalg.norm(y_all))
        if np.linalg.norm(y_all) > 0 else None)


def located_overlap(located: Sequence[Mapping[str, Any]],
                    regions: Sequence[np.ndarray | None] | None, labels: Sequence[str],
                    core: bool = False) -> float | None:
    """IoU of the located nodes against an effect region, over the snapshots scored.

    Parameters
    ----------
    located
        The diagnosis's ``check.located`` entries: ``snapshot`` (label), ``nodes``
        (first and last located node, inclusive) and, where recorded, ``core_nodes``
        (list of inclusive node ranges).
    regions
        One boolean array (n_s,) per snapshot (as ``labels``), e.g.
        :attr:`EffectRegions.raw`.
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
    if regions is None:
        return None
    located_nodes = [np.zeros(len(r), dtype=bool) for r in regions]
    for loc in located:
        k = list(labels).index(loc["snapshot"])
        if core and "core_nodes" not in loc:
            return None
        for a, b in loc["core_nodes"] if core else [loc["nodes"]]:
            located_nodes[k][a:b + 1] = True
    loc_all, reg_all = np.concatenate(located_nodes), np.concatenate(regions)
    union = np.sum(loc_all | reg_all)
    return float(np.sum(loc_all & reg_all) / union) if union else None
