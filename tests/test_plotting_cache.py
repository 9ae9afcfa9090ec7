"""Caches of the figure jobs (bayescalib.plotting): they change no figure.

* the process-wide cache of mathtext layouts (:func:`style._share_mathtext_layouts`)
  and the warm-up figure of the round job server (:func:`style.warm_up`): a figure
  saved in a fresh process and in one where the caches are warm (the same and other
  figures drawn before) is the same file, byte for byte;
* the memo of KDE results (:func:`_draw._memo`): contours and marginal KDE lines drawn
  from a warm memo are bitwise those computed afresh; other particles or weights are
  computed afresh.
"""

import subprocess
import sys

import numpy as np
from matplotlib.figure import Figure

from bayescalib.plotting import _draw
from bayescalib.plotting.style import paper_style

_FIGURE = """
import sys
import numpy as np
import matplotlib
matplotlib.use("Agg")
from bayescalib.plotting import plot_joint_posterior
from bayescalib.plotting.style import warm_up
if sys.argv[2] == "warm":
    warm_up()
    rng = np.random.default_rng(1)  # another figure first: other tick labels, same KDE code
    plot_joint_posterior(rng.normal([300, 0.1], [40, 0.2], (800, 2)), None, ["E", "nu"],
                         ["Pa", "-"], [sys.argv[1] + ".other.png"], dpi=80)
rng = np.random.default_rng(0)
X = rng.normal([400, 0.3], [60, 0.1], (2000, 2))
w = rng.random(2000)
for _ in range(2 if sys.argv[2] == "warm" else 1):  # the second from a warm memo
    plot_joint_posterior(X, w / w.sum(), ["E", "nu"], ["Pa", "-"], [sys.argv[1]], dpi=90,
                         bounds=np.array([[100.0, 800.0], [-0.8, 0.45]]))
"""


def test_figure_files_are_the_same_with_warm_caches(tmp_path):
    files = {}
    for mode in ("cold", "warm"):
        out = tmp_path / f"{mode}.png"
        subprocess.run([sys.executable, "-c", _FIGURE, str(out), mode], check=True)
        files[mode] = out.read_bytes()
    assert len(files["cold"]) > 10_000
    assert files["cold"] == files["warm"]


def test_mathtext_layouts_are_shared_between_renderers():
    from matplotlib import mathtext

    with paper_style():
        fig = Figure(figsize=(2, 2))
        fig.add_subplot().plot([0.0, 1e-5], [0.0, 1.0])
        fig.canvas.draw()
    assert getattr(mathtext.MathTextParser._parse_cached, "_bayescalib_shared", False)
    a, b = mathtext.MathTextParser("agg"), mathtext.MathTextParser("agg")
    from matplotlib.font_manager import FontProperties

    prop = FontProperties(size=8)
    assert a.parse(r"$\mathdefault{123}$", 100, prop) is b.parse(r"$\mathdefault{123}$", 100,
                                                                  prop)
    # another dpi is another layout
    assert a.parse(r"$\mathdefault{123}$", 100, prop) is not a.parse(r"$\mathdefault{123}$",
                                                                    200, prop)


def test_kde_memo_is_transparent_and_keyed_by_the_data():
    rng = np.random.default_rng(3)
    xy = rng.normal([0.0, 1.0], [1.0, 0.5], (3500, 2))
    w = rng.random(3500)
    w /= w.sum()
    box = [[-4.0, 4.0], [-1.0, 3.0]]

    def contours(weights):
        with paper_style():
            ax = Figure().add_subplot()
            cs = _draw.draw_hpd_contours(ax, xy, weights, box[0], box[1], [0.5, 0.9],
                                         support=box)
            line = _draw.draw_marginal(ax, xy[:, 0], weights, box[0], support=box[0])["kde"]
        return [s for level in cs.allsegs for s in level], line.get_ydata()

    _draw._MEMO.clear()
    cold = contours(w)
    n_entries = len(_draw._MEMO)
    assert n_entries == 3  # thresholds, grid, marginal
    warm = contours(w)
    assert len(_draw._MEMO) == n_entries  # nothing recomputed
    assert len(cold[0]) == len(warm[0]) >= 2
    assert all(np.array_equal(a, b) for a, b in zip(cold[0], warm[0], strict=True))
    assert np.array_equal(cold[1], warm[1])
    w2 = w.copy()
    w2[0] *= 2.0
    contours(w2 / w2.sum())
    assert len(_draw._MEMO) == 2 * n_entries  # other weights: computed afresh
