"""Shared figure style: rc context, colour-blind-safe palette and axis labels.

Every plotting function of :mod:`bayescalib.plotting` draws inside
:func:`paper_style`, so all figures share fonts, line widths and colours.
Figures are created as bare :class:`matplotlib.figure.Figure` objects (no
``pyplot`` state), which makes the package independent of the interactive
backend and safe to call from worker processes.

The palette is Okabe & Ito (2008), distinguishable under the common forms of
colour-vision deficiency. Semantic colours used across figures:

* posterior mean / global Gaussian approximation: orange
* MAP / Laplace approximation: bluish green
* ground truth: reddish purple
* prior densities: vermillion, dashed
* histograms / hexbins: blue (``Blues`` colormap)
* KDE lines: black
"""

from __future__ import annotations

import contextlib
import functools
import os
import re
from collections.abc import Iterator
from typing import Any

import matplotlib as mpl

__all__ = [
    "COLORS",
    "DENSITY_CMAP",
    "DIVERGING_CMAP",
    "OKABE_ITO",
    "SEQUENTIAL_CMAP",
    "axis_label",
    "density_label",
    "density_unit_label",
    "paper_style",
    "pretty_name",
    "warm_up",
]

#: Okabe-Ito palette, in its usual order.
OKABE_ITO: tuple[str, ...] = (
    "#000000",  # black
    "#E69F00",  # orange
    "#56B4E9",  # sky blue
    "#009E73",  # bluish green
    "#F0E442",  # yellow
    "#0072B2",  # blue
    "#D55E00",  # vermillion
    "#CC79A7",  # reddish purple
)

#: Semantic colours shared by all figures.
COLORS: dict[str, str] = {
    "kde": "#000000",
    "hist": "#0072B2",
    "mean": "#E69F00",
    "gaussian": "#E69F00",
    "map": "#009E73",
    "laplace": "#009E73",
    "truth": "#CC79A7",
    "prior": "#D55E00",
    "observed": "#000000",
    "reference": "#7F7F7F",
    "samples": "#0072B2",
    "failed": "#7F7F7F",
    "train": "#FFFFFF",
}

#: Colormap for scalar surfaces (likelihoods, fields): perceptually uniform.
SEQUENTIAL_CMAP = "viridis"
#: Colormap for weighted histograms of particles (high weight = dark blue).
DENSITY_CMAP = "Blues"
#: Diverging colormap for signed quantities centred at zero.
DIVERGING_CMAP = "RdBu_r"

_RC: dict[str, object] = {
    "font.size": 9.0,
    "axes.titlesize": 9.0,
    "axes.labelsize": 9.0,
    "xtick.labelsize": 8.0,
    "ytick.labelsize": 8.0,
    "legend.fontsize": 7.5,
    "legend.framealpha": 0.85,
    "legend.edgecolor": "0.8",
    "lines.linewidth": 1.2,
    "lines.markersize": 5.0,
    "axes.linewidth": 0.8,
    "axes.prop_cycle": mpl.cycler(color=list(OKABE_ITO)),
    "image.cmap": SEQUENTIAL_CMAP,
    "figure.dpi": 100.0,
    "savefig.bbox": "tight",
    "savefig.pad_inches": 0.03,
    "pdf.fonttype": 42,
    "ps.fonttype": 42,
    "axes.formatter.limits": (-3, 4),
    "axes.formatter.use_mathtext": True,
    "mathtext.default": "regular",
}

_GREEK = {
    "nu": "ν",
    "theta": "θ",
    "sigma": "σ",
    "mu": "μ",
    "lambda": "λ",
    "alpha": "α",
    "beta": "β",
    "gamma": "γ",
    "eta": "η",
    "rho": "ρ",
}
_SUBSCRIPT_DIGITS = str.maketrans("0123456789", "₀₁₂₃₄₅₆₇₈₉")
_DIMENSIONLESS = {"", "-", "1", "none"}


@contextlib.contextmanager
def paper_style() -> Iterator[None]:
    """Context manager applying the package's rc settings.

    Yields
    ------
    None
        Inside the block, matplotlib uses the paper style; the previous
        settings are restored on exit.
    """
    _share_mathtext_layouts()
    with mpl.rc_context(_RC):
        yield


def _share_mathtext_layouts() -> None:
    """One cache of laid-out mathtext strings for the whole process.

    The style typesets tick labels with mathtext (``axes.formatter.use_mathtext``), and
    Matplotlib lays out each string afresh for every renderer (its cache,
    ``MathTextParser._parse_cached``, is keyed by the parser instance, one per
    renderer, and holds 50 entries): the same tick labels were laid out again for every
    figure, every layout pass and every saved format, which took most of the posterior
    figures' time (205 layouts of 78 distinct strings, 80 % of the job's CPU time in the
    python64 study). Here the cache is keyed by what the layout depends on (the
    parser's output type, the string, dpi, font properties, antialiasing, glyph
    flags) and holds 4096 entries; the results are the very objects Matplotlib's own
    cache shares between calls, so figures are unchanged (bitwise: the files are the
    same). A no-op where Matplotlib's internals differ from this layout.
    """
    from matplotlib import mathtext

    cls = mathtext.MathTextParser
    current = getattr(cls, "_parse_cached", None)
    inner = getattr(current, "__wrapped__", None)
    if current is None or inner is None or getattr(current, "_bayescalib_shared", False):
        return

    @functools.lru_cache(maxsize=4096)
    def shared(output_type, first, s, dpi, prop, antialiased, load_glyph_flags):
        return inner(first, s, dpi, prop, antialiased, load_glyph_flags)

    def _parse_cached(self, s, dpi, prop, antialiased, load_glyph_flags):
        # ``self`` enters the layout only through its output type (the font set and
        # the parser are class attributes); the first parser of a type does the work
        first = _FIRST_PARSER.setdefault(self._output_type, self)
        return shared(self._output_type, first, s, dpi, prop, antialiased,
                      load_glyph_flags)

    _parse_cached._bayescalib_shared = True  # type: ignore[attr-defined]
    cls._parse_cached = _parse_cached
    # a layout holds the FreeType font objects it was made with, and those read their
    # glyphs from an open font file: a forked child sharing the file (and its offset)
    # with its parent and siblings read corrupt outlines when two figure jobs forked from
    # the warm round server drew at once ("FT_Load_Glyph ... invalid outline", "too many
    # hints"). A child starts with an empty cache, as Matplotlib's own font cache does.
    os.register_at_fork(after_in_child=shared.cache_clear)
    _SHARED_LAYOUTS.append(shared)


#: the first MathTextParser of each output type (kept alive: it keys the shared cache)
_FIRST_PARSER: dict[str, object] = {}
#: the process-wide layout cache, once made (emptied in every forked child)
_SHARED_LAYOUTS: list[Any] = []


def warm_up(dpi: float = 150.0, formats: tuple[str, ...] = ("png", "pdf")) -> None:
    """Draw and save (to memory) one small figure in the paper style.

    For a process that forks the figure jobs (the round job server): what every
    process pays on its first figure and does not depend on the figure (the mathtext
    grammar, the fonts and their glyph caches, the PNG writer) is paid once here and
    inherited by every job, about a third of a small figure job's CPU time. Draws
    nothing to disk; figures drawn later are unchanged.

    Parameters
    ----------
    dpi : float
        Resolution of the throw-away PNG [dots per inch] (the default figure dpi of
        the config schema, so that its tick labels' layouts are cached too).
    formats : tuple of str
        The formats written (to memory): the schema's default figure formats.
    """
    import io

    from matplotlib.figure import Figure

    with paper_style():
        fig = Figure(figsize=(3.0, 2.4), layout="constrained")
        ax = fig.add_subplot()
        ax.plot([100.0, 800.0], [-0.8, 0.45], label="line")
        ax.scatter([300.0, 500.0], [0.0, 0.2], s=4)
        ax.set_xlabel(axis_label("E", "Pa"))
        ax.set_ylabel(axis_label("nu", "-"))
        ax.set_title("warm-up")
        ax.legend()
        for fmt in formats:
            fig.savefig(io.BytesIO(), format=fmt, dpi=dpi)
        fig.clear()


def pretty_name(name: str) -> str:
    """Typeset a parameter name for axis labels.

    Greek names become the Greek letter and trailing digits become Unicode
    subscripts: ``"nu"`` -> ``"ν"``, ``"E2"`` -> ``"E₂"``, ``"nu_3"`` -> ``"ν₃"``.
    Any other name is returned unchanged.

    Parameters
    ----------
    name : str
        Parameter name as used in the configuration.

    Returns
    -------
    str
        Display name.
    """
    m = re.fullmatch(r"([A-Za-z]+)_?(\d+)?", name)
    if m is None:
        return name
    base, digits = m.group(1), m.group(2)
    base = _GREEK.get(base, base)
    return base + (digits.translate(_SUBSCRIPT_DIGITS) if digits else "")


def _unit_text(unit: str) -> str:
    return "-" if unit.strip().lower() in _DIMENSIONLESS else unit.strip()


def axis_label(name: str, unit: str) -> str:
    """Axis label ``"<name> [<unit>]"``, e.g. ``"E [Pa]"`` or ``"ν [-]"``.

    Parameters
    ----------
    name : str
        Parameter name (typeset with :func:`pretty_name`).
    unit : str
        Unit; empty, ``"-"``, ``"1"`` or ``"none"`` mean dimensionless.

    Returns
    -------
    str
        The label.
    """
    return f"{pretty_name(name)} [{_unit_text(unit)}]"


def density_unit_label(unit: str) -> str:
    """Short label of a 1-D density axis, e.g. ``"density [1/Pa]"``."""
    u = _unit_text(unit)
    return "density [-]" if u == "-" else f"density [1/{u}]"


def density_label(name: str, unit: str) -> str:
    """Label for a marginal density axis, e.g. ``"p(E | y) [1/Pa]"``.

    Parameters
    ----------
    name : str
        Parameter name.
    unit : str
        Unit of the parameter; the density has the inverse unit.

    Returns
    -------
    str
        The label.
    """
    u = _unit_text(unit)
    inv = "-" if u == "-" else f"1/{u}"
    return f"p({pretty_name(name)} | y) [{inv}]"
