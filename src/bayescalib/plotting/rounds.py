"""Active design rounds: where each round's posterior lay, where its solves went,
and the two checks of the stop rule per round, the trust check and the posterior check
(:mod:`bayescalib.inference.active`; terms: docs/glossary.md)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from ._validation import PathsLike, as_names_units, as_paths, finish
from .style import COLORS, axis_label, paper_style

__all__ = ["plot_rounds"]


def _shown_rounds(n: int, k: int) -> list[int]:
    """Up to ``k`` round indices out of ``n``, always the first and the last."""
    if n <= k:
        return list(range(n))
    return sorted({round(v) for v in np.linspace(0, n - 1, k)})


def _check_verdict(pc: Mapping[str, Any]) -> str:
    """A look of the posterior check in the stop-rule panel's words: confirmed, NOT
    confirmed (refuted), undecided (its next look follows) or superseded (stopped: the
    posterior moved away from the checked one)."""
    decision = pc.get("decision")  # absent in records from before the sequential check
    if decision == "continue":
        return "undecided"
    if decision == "superseded":
        return "superseded"
    return "confirmed" if pc["confirmed"] else "NOT confirmed"


def plot_rounds(
    draws: Sequence[np.ndarray],
    design: np.ndarray,
    n_solves: Sequence[int],
    batches: Sequence[np.ndarray | None],
    shift_sd: Sequence[float | None],
    gp_error: Sequence[float | None],
    names: Sequence[str],
    units: Sequence[str],
    paths: PathsLike,
    *,
    bounds: Sequence[Sequence[float]],
    shift_tol: float,
    gp_tol: float,
    converged: bool,
    truth: Sequence[float] | None = None,
    failed: np.ndarray | None = None,
    batch_kinds: Sequence[Sequence[str] | None] | None = None,
    posterior_check: Sequence[Mapping[str, Any] | None] | None = None,
    max_panels: int = 6,
    dpi: float = 200,
    return_figure: bool = False,
):
    """Posterior and design points per round, and the stop rule's trust check and
    posterior check.

    Parameters
    ----------
    draws : sequence of arrays (m_r, 2)
        Equal-weight posterior draws of each round, in the two shown parameters.
    design : array (n, 2)
        All design points in solve order (the first ``n_solves[r]`` belong to round <= r).
    n_solves : sequence of int
        Solves after each round.
    batches : sequence of arrays (q, 2) or None
        The batch each round chose for the next (None where it stopped).
    shift_sd, gp_error : sequences of float or None
        Posterior change since the previous round (sd) and the largest error of the
        previous round's surrogate at this round's solves in the posterior region
        (nats); None where not defined (round 0).
    names, units : two parameter names and units.
    paths : output files.
    bounds : (2, 2) axis ranges (the design box).
    shift_tol, gp_tol : tolerances of the stop rule (drawn as lines).
    converged : whether the last round met the stop rule (title).
    truth : (2,) ground truth, optional.
    failed : (F, 2) points whose solves failed, optional.
    batch_kinds : sequence of (q,) sequences of str or None, optional
        Per round, what each point of its batch is: ``"acquired"`` (chosen by the
        acquisition), ``"check"`` (a random check point, drawn without the
        surrogate), ``"boundary"`` (a midpoint between a failed and a successful solve,
        :func:`bayescalib.inference.active.boundary_points`) or ``"posterior_check"``
        (a check round's posterior draw); absent = all acquired.
    posterior_check : sequence of dict or None, optional
        Per round, the posterior check of the previous round's posterior judged there
        (``log_weight_sd`` in nats, ``confirmed``, ``decision``), None where there was
        none. Drawn in
        the stop-rule panel (filled: confirmed); with check rounds the trust check's
        tolerance is drawn as reported, not deciding.
    max_panels : most rounds drawn as panels (first and last always).
    """
    names, units = as_names_units(names, units, 2)
    out_paths = as_paths(paths)
    n = len(draws)
    if not (len(n_solves) == len(batches) == len(shift_sd) == len(gp_error) == n) or n == 0:
        raise ValueError("plot_rounds: one entry per round expected in every sequence")
    X = np.atleast_2d(np.asarray(design, float))
    b = np.asarray(bounds, float)
    shown = _shown_rounds(n, max_panels)
    ncols = min(len(shown), 3)
    nrows = int(np.ceil(len(shown) / ncols)) + 1
    with paper_style():
        fig = Figure(figsize=(3.0 * ncols, 2.7 * nrows), layout="constrained")
        gs = fig.add_gridspec(nrows, ncols)
        panels = []
        for k, r in enumerate(shown):
            ax = fig.add_subplot(gs[k // ncols, k % ncols])
            d = np.atleast_2d(np.asarray(draws[r], float))
            ax.scatter(d[:, 0], d[:, 1], s=2, c=COLORS["hist"], alpha=0.25, lw=0,
                       label="posterior draws")
            old = X[: n_solves[r - 1]] if r > 0 else np.empty((0, 2))
            new = X[(n_solves[r - 1] if r > 0 else 0): n_solves[r]]
            ax.plot(*old.T, ls="none", marker="o", ms=3, mfc="0.6", mec="none",
                    label="earlier solves")
            ax.plot(*new.T, ls="none", marker="o", ms=4, mfc=COLORS["mean"], mec="k", mew=0.3,
                    label="this round's solves")
            if batches[r] is not None and len(batches[r]):
                nb = np.atleast_2d(np.asarray(batches[r], float))
                kinds = batch_kinds[r] if batch_kinds is not None else None
                is_check_point = (np.asarray(kinds) == "check" if kinds is not None
                            else np.zeros(len(nb), bool))
                draw = (np.asarray(kinds) == "posterior_check" if kinds is not None
                        else np.zeros(len(nb), bool))
                if is_check_point.shape != (len(nb),):
                    raise ValueError(f"plot_rounds: round {r} has {len(nb)} batch points "
                                     f"but {is_check_point.size} kinds")
                edge = (np.asarray(kinds) == "boundary" if kinds is not None
                        else np.zeros(len(nb), bool))
                if np.any(~is_check_point & ~draw & ~edge):
                    ax.plot(*nb[~is_check_point & ~draw & ~edge].T, ls="none", marker="x", ms=5,
                            color=COLORS["map"], label="chosen for next round")
                if edge.any():
                    ax.plot(*nb[edge].T, ls="none", marker="s", ms=4, mfc="none",
                            mec="k", mew=0.8,
                            label="boundary of the failed region, next round")
                if draw.any():
                    ax.plot(*nb[draw].T, ls="none", marker="+", ms=6, color=COLORS["map"],
                            label="posterior check's draws, next round")
                if is_check_point.any():
                    ax.plot(*nb[is_check_point].T, ls="none", marker="D", ms=4, mfc="none",
                            mec=COLORS["map"], mew=0.8, label="random check point, next round")
            if failed is not None and len(failed):
                f = np.atleast_2d(np.asarray(failed, float))
                ax.plot(*f.T, ls="none", marker="x", ms=4, color="k", label="failed solves")
            if truth is not None:
                ax.plot(*truth, ls="none", marker="*", ms=10, mfc=COLORS["truth"], mec="k",
                        mew=0.5, label="ground truth", zorder=5)
            ax.set_xlim(*b[0])
            ax.set_ylim(*b[1])
            ax.set_title(f"round {r}: {n_solves[r]} solves", fontsize=8)
            ax.set_xlabel(axis_label(names[0], units[0]))
            ax.set_ylabel(axis_label(names[1], units[1]))
            panels.append(ax)
        # one legend for all panels (a check round's draws appear only in later ones)
        entries: dict[str, Any] = {}
        for pax in panels:
            for h, lab in zip(*pax.get_legend_handles_labels(), strict=True):
                entries.setdefault(lab, h)
        panels[0].legend(list(entries.values()), list(entries), loc="best", fontsize=6,
                         markerscale=1.2)
        ax = fig.add_subplot(gs[nrows - 1, :])
        rr = np.arange(n)
        sh = np.array([np.nan if v is None else v for v in shift_sd], float)
        ge = np.array([np.nan if v is None else v for v in gp_error], float)
        ax.semilogy(rr, sh, marker="o", color=COLORS["mean"],
                    label="posterior change [posterior sd]")
        ax.semilogy(rr, ge, marker="s", color=COLORS["hist"],
                    label="surrogate error at new solves [nats]")
        ax.axhline(shift_tol, color=COLORS["mean"], ls="--", lw=0.8,
                   label=f"tolerance {shift_tol:g} sd")
        pcs = list(posterior_check) if posterior_check is not None else [None] * n
        judged = [r for r in range(n) if pcs[r] is not None
                  and pcs[r].get("log_weight_sd") is not None]
        ax.axhline(gp_tol, color=COLORS["hist"], ls=":", lw=0.8,
                   label=(f"tolerance {gp_tol:g} nats (reported; the posterior check decides)"
                          if judged else f"tolerance {gp_tol:g} nats"))
        for verdict, marker, filled in (("confirmed", "P", True), ("NOT confirmed", "P", False),
                                        ("undecided", "x", False),
                                        ("superseded", "D", False)):
            rr_v = [r for r in judged if _check_verdict(pcs[r]) == verdict]
            if rr_v:
                ax.semilogy(rr_v, [max(pcs[r]["log_weight_sd"], 1e-3) for r in rr_v],
                            ls="none", marker=marker, ms=8, color=COLORS["map"],
                            mfc=COLORS["map"] if filled else "none",
                            label="posterior check of the round before: log-weight sd "
                                  f"[nats], {verdict}")
        ax.set_xlabel("round")
        ax.set_xticks(rr)
        ax.set_ylabel("stop-rule checks")
        ax.legend(loc="upper right", fontsize=6, ncols=2)
        state = "converged" if converged else "NOT converged (budget spent)"
        fig.suptitle(f"Active design: {n} rounds, {n_solves[-1]} solves, {state}", fontsize=9)
        return finish(fig, out_paths, dpi, return_figure)
