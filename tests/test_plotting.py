"""Tests of bayescalib.plotting: files written, labels with units, HPD
thresholds against the analytic 2-D Gaussian, ellipse geometry, weighted
histograms, and input validation.

Set BAYESCALIB_PLOT_DIR to keep the rendered figures for visual inspection.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from _gaussian import COV, MEAN
from matplotlib.collections import LineCollection, PolyCollection

from bayescalib.inference.weights import weighted_kde
from bayescalib.plotting import (
    axis_label,
    chi2_radius2,
    ellipse_axes,
    ellipse_points,
    plot_fields,
    plot_gp_convergence,
    plot_interface_residual,
    plot_interfaces,
    plot_joint_posterior,
    plot_marginals_1d,
    plot_pair_marginals,
    plot_parallel_axes,
    plot_particles,
    plot_response_surface,
)
from bayescalib.plotting.interfaces import deflection_profile
from bayescalib.plotting.parallel import select_lines

NAMES, UNITS = ["E", "nu"], ["Pa", "-"]
BOUNDS = ((100.0, 800.0), (-0.8, 0.5))


@pytest.fixture
def outdir(tmp_path: Path) -> Path:
    keep = os.environ.get("BAYESCALIB_PLOT_DIR")
    if keep:
        p = Path(keep)
        p.mkdir(parents=True, exist_ok=True)
        return p
    return tmp_path


def _labels(fig) -> set[str]:
    out = set()
    for ax in fig.axes:
        out |= {ax.get_xlabel(), ax.get_ylabel()}
    return out


def _check_files(paths, expected):
    assert [Path(p) for p in paths] == [Path(p) for p in expected]
    for p in expected:
        assert Path(p).is_file() and Path(p).stat().st_size > 1000, p
    png = Path(expected[0]).read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert Path(expected[1]).read_bytes()[:5] == b"%PDF-"


def _uniform(lo, hi):
    return lambda x: np.where((x >= lo) & (x <= hi), 1.0 / (hi - lo), 0.0)


# --------------------------------------------------------------------------- style / labels
def test_axis_labels_typeset_names_and_units():
    assert axis_label("E", "Pa") == "E [Pa]"
    assert axis_label("nu", "-") == "ν [-]"
    assert axis_label("nu", "") == "ν [-]"
    assert axis_label("E2", "Pa") == "E₂ [Pa]"
    assert axis_label("nu_3", "1") == "ν₃ [-]"
    assert axis_label("V_in", "mm^2/s") == "V_in [mm^2/s]"


# --------------------------------------------------------------------------- HPD thresholds
# --------------------------------------------------------------------------- ellipses
def test_ellipse_axes_of_diagonal_covariance():
    semi, angle = ellipse_axes(np.diag([4.0, 1.0]), 0.9)
    r = np.sqrt(-2 * np.log(0.1))
    np.testing.assert_allclose(semi, [2 * r, r])
    assert angle == pytest.approx(0.0, abs=1e-12)
    semi, angle = ellipse_axes(np.diag([1.0, 9.0]), 0.5)
    assert angle == pytest.approx(np.pi / 2)
    np.testing.assert_allclose(semi, np.sqrt(chi2_radius2(0.5)) * np.array([3.0, 1.0]))


def test_ellipse_of_rotated_covariance_has_correct_axes_and_mass():
    th = np.deg2rad(30.0)
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    cov = R @ np.diag([9.0, 1.0]) @ R.T
    semi, angle = ellipse_axes(cov, 0.9)
    assert angle == pytest.approx(th)
    r = np.sqrt(chi2_radius2(0.9))
    np.testing.assert_allclose(semi, [3 * r, r])
    pts = ellipse_points([1.0, -2.0], cov, 0.9)
    d = pts - [1.0, -2.0]
    maha = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
    np.testing.assert_allclose(maha, r**2)
    # extreme distance from the centre is the major semi-axis
    assert np.max(np.hypot(d[:, 0], d[:, 1])) == pytest.approx(3 * r, rel=1e-3)
    # probability mass inside: Monte Carlo, 5 sigma of a binomial proportion
    rng = np.random.default_rng(3)
    z = rng.multivariate_normal([0, 0], cov, size=20000)
    inside = np.einsum("ni,ij,nj->n", z, np.linalg.inv(cov), z) <= r**2
    assert abs(inside.mean() - 0.9) < 5 * np.sqrt(0.09 / 20000)


def test_ellipse_rejects_invalid_covariance():
    with pytest.raises(ValueError, match="positive definite"):
        ellipse_axes([[1.0, 2.0], [2.0, 1.0]], 0.9)
    with pytest.raises(ValueError, match="symmetric"):
        ellipse_points([0, 0], [[1.0, 0.5], [0.0, 1.0]], 0.9)
    with pytest.raises(ValueError, match=r"\(0, 1\)"):
        chi2_radius2(1.0)


def test_mass_outside_box_against_closed_forms():
    from scipy.stats import norm

    from bayescalib.plotting.gaussian import mass_outside_box

    # independent axes: inside = product of the 1-D masses
    m, c = np.array([1.0, -2.0]), np.diag([0.5**2, 2.0**2])
    box = ((0.2, 1.9), (-5.0, 0.0))
    inside = ((norm.cdf(1.9, 1.0, 0.5) - norm.cdf(0.2, 1.0, 0.5))
              * (norm.cdf(0.0, -2.0, 2.0) - norm.cdf(-5.0, -2.0, 2.0)))
    assert mass_outside_box(m, c, box) == pytest.approx(1.0 - inside, abs=1e-6)
    # a correlated Gaussian cut by a line through its mean: half its mass, any correlation
    assert mass_outside_box([0.0, 0.0], [[1.0, 0.9], [0.9, 1.0]],
                            ((-np.inf, np.inf), (0.0, np.inf))) == pytest.approx(0.5, abs=1e-6)
    assert mass_outside_box([0.0, 0.0], np.eye(2), ((5.0, 6.0), (0.0, 1.0))) > 0.999


def test_joint_legend_says_when_an_approximation_is_clipped_by_the_box(outdir, weighted_gaussian):
    x, w = weighted_gaussian
    # a Gaussian centred on the bound nu = 0.5: half of it lies outside the box
    _, fig = plot_joint_posterior(x, w, NAMES, UNITS, [outdir / "joint_clip.png"],
                                  gaussian=((400.0, 0.5), COV), laplace=(MEAN, 0.5 * COV),
                                  bounds=BOUNDS, return_figure=True)
    texts = [t.get_text() for ax in fig.axes if ax.get_legend()
             for t in ax.get_legend().get_texts()]
    gauss = next(t for t in texts if t.startswith("Gaussian approx."))
    assert "50 % of its mass outside the box: clipped" in gauss
    assert "Laplace approx. (90 %)" in texts  # well inside: no note


# --------------------------------------------------------------------------- figures
def test_joint_posterior(outdir, weighted_gaussian):
    x, w = weighted_gaussian
    paths = [outdir / "joint.png", outdir / "joint.pdf"]
    written, fig = plot_joint_posterior(
        x, w, NAMES, UNITS, paths, prior_pdfs=(_uniform(*BOUNDS[0]), _uniform(*BOUNDS[1])),
        map=x[np.argmax(w)], mean=w @ x, gaussian=(w @ x, np.cov(x.T, aweights=w)),
        laplace=(MEAN, 0.5 * COV), truth=(400, 0.3), bounds=BOUNDS, return_figure=True)
    _check_files(written, paths)
    labels = _labels(fig)
    assert {"E [Pa]", "ν [-]", "posterior mass per hexagon [-]", "density [1/Pa]",
            "density [-]"} <= labels
    legend_texts = {t.get_text() for ax in fig.axes if ax.get_legend()
                    for t in ax.get_legend().get_texts()}
    assert {"MAP", "posterior mean", "prior", "ground truth", "Gaussian approx. (90 %)",
            "Laplace approx. (90 %)", "KDE HPD regions 50 %, 90 %, 99 %"} <= legend_texts
    # the hexbin's colour bar lies under the joint panel, across its width, not beside
    # the right-hand marginal (where it read as that marginal's scale)
    fig.canvas.draw()
    cax = next(ax for ax in fig.axes if ax.get_xlabel() == "posterior mass per hexagon [-]")
    joint = next(ax for ax in fig.axes if ax.get_xlabel() == "E [Pa]" and ax.get_ylabel())
    cb, jb = cax.get_position(), joint.get_position()
    assert cb.y1 < jb.y0 and cb.x0 >= jb.x0 - 0.02 and cb.x1 <= jb.x1 + 0.02, (cb, jb)
    # the hexbin shows probability mass: all particles are inside the bounds
    hexbins = [c for ax in fig.axes for c in ax.collections
               if isinstance(c, PolyCollection) and c.get_array() is not None]
    inside = np.all((x >= np.array(BOUNDS)[:, 0]) & (x <= np.array(BOUNDS)[:, 1]), axis=1)
    assert hexbins[0].get_array().sum() == pytest.approx(w[inside].sum())


def test_a_map_on_the_truth_stays_visible(outdir, weighted_gaussian):
    """A MAP that hits the ground truth is drawn on top of the truth's star."""
    x, w = weighted_gaussian
    _, fig = plot_joint_posterior(x, w, NAMES, UNITS, [outdir / "joint_map.png"],
                                  map=(400.0, 0.3), truth=(400.0, 0.3), bounds=BOUNDS,
                                  return_figure=True)
    lines = {ln.get_label(): ln for ax in fig.axes for ln in ax.get_lines()}
    assert lines["MAP"].get_zorder() > lines["ground truth"].get_zorder()


def test_response_surface(outdir):
    gx, gy = np.linspace(100, 800, 40), np.linspace(-0.8, 0.5, 30)
    E, N = np.meshgrid(gx, gy)
    L = -0.5 * ((E - 400) / 100) ** 2 - 0.5 * ((N - 0.2) / 0.2) ** 2
    rng = np.random.default_rng(4)
    Xt = np.column_stack([rng.uniform(100, 800, 30), rng.uniform(-0.8, 0.5, 30)])
    paths = [outdir / "response.png", outdir / "response.pdf"]
    written, fig = plot_response_surface(gx, gy, L, 0.1 + 0 * L, Xt[Xt[:, 0] > 150],
                                         Xt[Xt[:, 0] <= 150], NAMES, UNITS, paths,
                                         truth=(400, 0.3), return_figure=True)
    _check_files(written, paths)
    assert {"E [Pa]", "ν [-]", "exp(L - max L) [-]", "L [nats]", "sd of L [nats]"} \
        <= _labels(fig)
    # log-likelihoods are in nats, never "[-]"; every panel has a title and both axes
    assert not any("log-likelihood [-]" in t or "of L [-]" in t for t in _labels(fig))
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert [ax.get_title()[:3] for ax in panels] == ["(a)", "(b)", "(c)"]
    assert all(ax.get_xlabel() == "E [Pa]" and ax.get_ylabel() == "ν [-]" for ax in panels)
    mesh = fig.axes[0].collections[0]
    assert mesh.get_array().max() == pytest.approx(1.0)
    # without std only two panels (plus their colour bars)
    _, fig2 = plot_response_surface(gx, gy, L, None, Xt, None, NAMES, UNITS,
                                    [outdir / "response2.png"], return_figure=True)
    assert "sd of L [nats]" not in _labels(fig2)
    with pytest.raises(ValueError, match="loglik"):
        plot_response_surface(gx, gy, L.T, None, Xt, None, NAMES, UNITS, [outdir / "x.png"])


def test_gp_convergence(outdir):
    n = np.array([10, 20, 50, 100, 200])
    e = 3.0 * n**-0.7
    paths = [outdir / "convergence.png", outdir / "convergence.pdf"]
    written, fig = plot_gp_convergence(n, e, 1.2 * e, paths, relative=True, return_figure=True)
    _check_files(written, paths)
    ax = fig.axes[0]
    assert ax.get_xscale() == "log" and ax.get_yscale() == "log"
    assert ax.get_ylabel() == "relative L2 error of log-likelihood [-]"
    assert len(ax.get_lines()) == 2
    with pytest.raises(ValueError, match="positive"):
        plot_gp_convergence(n, -e, None, [outdir / "x.png"])


def test_particles(outdir, weighted_gaussian):
    x, w = weighted_gaussian
    paths = [outdir / "particles.png", outdir / "particles.pdf"]
    written, fig = plot_particles(x, w, NAMES, UNITS, paths, bounds=BOUNDS, return_figure=True)
    _check_files(written, paths)
    assert {"E [Pa]", "ν [-]", "particle weight [-]"} <= _labels(fig)
    sc = fig.axes[0].collections[0]
    sizes, colours = sc.get_sizes(), sc.get_array()
    assert np.all(np.diff(colours) >= 0)  # heaviest drawn last
    assert sizes[-1] == pytest.approx(60.0) and np.all(np.diff(sizes) >= -1e-12)


def test_marginals_1d(outdir, weighted_gaussian):
    x, w = weighted_gaussian
    paths = [outdir / "marginals.png", outdir / "marginals.pdf"]
    written, fig = plot_marginals_1d(
        x, w, NAMES, UNITS, paths, prior_pdfs=[_uniform(*BOUNDS[0]), None],
        map=x[np.argmax(w)], mean=w @ x, truth=(400, 0.3), bounds=BOUNDS, return_figure=True)
    _check_files(written, paths)
    assert {"E [Pa]", "ν [-]", "density [1/Pa]", "density [-]"} <= _labels(fig)
    # the filled histogram is a density: it integrates to the mass inside the bounds
    stairs = fig.axes[0].patches[0]
    vals, edges = stairs.get_data().values, stairs.get_data().edges
    inside = (x[:, 0] >= BOUNDS[0][0]) & (x[:, 0] <= BOUNDS[0][1])
    assert np.sum(vals * np.diff(edges)) == pytest.approx(w[inside].sum(), abs=1e-12)


@pytest.mark.parametrize("d", [2, 3, 5, 7])
def test_pair_marginals_any_dimension(outdir, d):
    rng = np.random.default_rng(d)
    A = np.eye(d) + 0.3 * rng.normal(size=(d, d))
    x = rng.normal(size=(300, d)) @ A.T
    w = rng.uniform(0.5, 1.0, 300)
    names = [f"E{k}" for k in range(d)]
    units = ["Pa"] * d
    paths = [outdir / f"pairs{d}.png", outdir / f"pairs{d}.pdf"]
    written, fig = plot_pair_marginals(x, w, names, units, paths, truth=np.zeros(d),
                                       return_figure=True)
    _check_files(written, paths)
    visible = [ax for ax in fig.axes if ax.get_visible() and ax.get_label() != "<colorbar>"]
    assert len(visible) == d * (d + 1) // 2
    labels = _labels(fig)
    assert {f"E{chr(0x2080 + k)} [Pa]" for k in range(d)} <= labels
    assert "posterior mass per hexagon [-]" in labels


def test_pair_marginals_rejects_too_many_dimensions(outdir):
    x = np.random.default_rng(0).normal(size=(50, 8))
    with pytest.raises(ValueError, match="number of parameters 8"):
        plot_pair_marginals(x, None, list("abcdefgh"), ["-"] * 8, [outdir / "x.png"])


def test_parallel_axes(outdir):
    rng = np.random.default_rng(5)
    x = rng.normal(size=(3000, 4))
    logd = -0.5 * np.sum(x**2, axis=1)
    names, units = ["E1", "nu1", "E2", "V_in"], ["Pa", "-", "Pa", "mm^2/s"]
    paths = [outdir / "parallel.png", outdir / "parallel.pdf"]
    written, fig = plot_parallel_axes(x, logd, names, units, paths, values_are_log=True,
                                      max_lines=500, return_figure=True)
    _check_files(written, paths)
    ax = fig.axes[0]
    ticks = [t.get_text() for t in ax.get_xticklabels()]
    # a log-density has no unit of its own: no "[-]" after it
    assert ticks == ["E₁ [Pa]", "ν₁ [-]", "E₂ [Pa]", "V_in [mm^2/s]", "log posterior density"]
    lc = next(c for c in ax.collections if isinstance(c, LineCollection))
    arr = lc.get_array()
    assert arr.size == 500
    assert np.all(np.diff(arr) >= 0) and arr[-1] == logd.max()  # best line on top
    assert "log posterior density" in _labels(fig) and "log posterior density [-]" not in _labels(fig)
    # the colour range is that of the lines drawn (no overshoot past the data shown)
    assert (lc.norm.vmin, lc.norm.vmax) == (arr.min(), arr.max())
    _, fig = plot_parallel_axes(x, logd, names, units, [outdir / "parallel2.png"],
                                values_are_log=True, value_name="log posterior density",
                                show_value_axis=False, return_figure=True)
    assert "log posterior density" in _labels(fig)
    assert len(fig.axes[0].get_xticklabels()) == 4


def test_parallel_axes_stop_at_the_prior_box_and_name_its_bounds(outdir):
    """The axes ran past the box (nu's bound 0.5 unlabelled, lines drawn up to the axes'
    padding); now each axis spans its bounds only, labels them, and no line leaves it."""
    rng = np.random.default_rng(6)
    x = np.column_stack([rng.uniform(100, 800, 400), rng.uniform(-0.8, 0.5, 400)])
    x[0] = [850.0, 0.6]  # beyond the box: drawn at its edge
    _, fig = plot_parallel_axes(x, -np.sum(x**2, axis=1) / 1e5, NAMES, UNITS,
                                [outdir / "parallel_box.png"], values_are_log=True,
                                bounds=BOUNDS, return_figure=True)
    ax = fig.axes[0]
    lc = next(c for c in ax.collections if isinstance(c, LineCollection))
    ys = np.concatenate([seg[:, 1] for seg in lc.get_segments()])
    assert ys.min() >= 0.0 and ys.max() <= 1.0
    axis_lines = [ln for ln in ax.get_lines() if np.ptp(ln.get_xdata()) == 0
                  and np.ptp(ln.get_ydata()) > 0.5]
    assert len(axis_lines) == 3  # E, nu and the value axis
    assert all(tuple(ln.get_ydata()) == (0.0, 1.0) for ln in axis_lines)
    labels = {t.get_text() for t in ax.texts}
    assert {"100", "800", "-0.8", "0.5"} <= labels


def test_select_lines_keeps_top_and_orders_by_value():
    v = np.arange(100.0)[::-1]
    idx = select_lines(v, 20, seed=1)
    assert idx.size == 20
    assert set(np.argsort(v)[::-1][:2]) <= set(idx)
    assert np.all(np.diff(v[idx]) >= 0)
    assert select_lines(v, 200).size == 100


def _bump(shift, n=150):
    s = np.linspace(0, 2, n)
    g = np.exp(-(((s - 1.0) / 0.3) ** 2))
    return np.column_stack([s + shift * g, 0.3 * g * (1 - shift)])


def test_interfaces(outdir):
    ref, obs = _bump(0.0), _bump(0.1)
    samples = [_bump(s) for s in np.linspace(0.05, 0.15, 20)]
    paths = [outdir / "interfaces.png", outdir / "interfaces.pdf"]
    written, fig = plot_interfaces(ref, obs, samples, paths, map_interface=_bump(0.09),
                                   return_figure=True)
    _check_files(written, paths)
    assert len(fig.axes) == 2  # overview + deflection profile
    assert fig.axes[0].get_xlabel() == "x [mm]" and fig.axes[0].get_ylabel() == "y [mm]"
    assert fig.axes[0].get_aspect() == 1.0
    # deflections below 0.1 mm: the profile is in micrometres; 20 samples, 20 lines
    assert fig.axes[1].get_ylabel() == "deflection [µm]"
    assert len(fig.axes[1].collections[0].get_segments()) == 20
    texts = {t.get_text() for t in fig.legends[0].get_texts()}
    assert {"undeformed", "observed", "MAP", "posterior samples (20)"} <= texts
    # list of snapshots and metres -> mm conversion
    written, fig = plot_interfaces(ref * 1e-3, [obs * 1e-3, _bump(0.12) * 1e-3], None,
                                   [outdir / "interfaces_snap.png"], profile=False,
                                   length_unit_factor=1e3, return_figure=True)
    assert len(fig.axes) == 1
    assert fig.axes[0].get_xlim()[1] == pytest.approx(2.1, abs=0.05)  # mm, not m


def test_deflection_profile_of_a_normal_offset_is_that_offset_along_the_arc():
    """A curve moved by a constant distance along the normals of a circle arc (a
    concentric arc) deflects by exactly that distance everywhere, with the sign of the
    side (left of the direction of travel = positive); its foot points run along the
    arc length of the reference."""
    phi = np.linspace(np.pi, 0.0, 200)  # left to right over the top: normals point out
    ref = np.column_stack([np.cos(phi), np.sin(phi)])
    for r, sign in ((1.02, 1.0), (0.97, -1.0)):
        s, d = deflection_profile(ref, r * ref)
        assert np.allclose(d, sign * abs(r - 1.0), atol=1e-4)  # chord vs arc: 1e-4
        assert s[0] == pytest.approx(0.0, abs=1e-3)  # foot on the first chord
        assert s[-1] == pytest.approx(np.pi, rel=1e-3)
        assert np.all(np.diff(s) >= 0)


def test_interface_residual(outdir):
    pts = _bump(0.1)
    vals = np.sin(np.linspace(0, 6, pts.shape[0])) * 2.5
    paths = [outdir / "residual.png", outdir / "residual.pdf"]
    written, fig = plot_interface_residual(pts, vals, paths, reference=_bump(0.0),
                                           return_figure=True)
    _check_files(written, paths)
    assert "standardized residual [-]" in _labels(fig)
    lc = next(c for c in fig.axes[0].collections if isinstance(c, LineCollection))
    assert lc.norm.vmin == pytest.approx(-lc.norm.vmax) and lc.norm(0.0) == pytest.approx(0.5)


def _channel(nx=41, ny=21):
    xs, ys = np.linspace(0, 2, nx), np.linspace(0, 1, ny)
    X, Y = np.meshgrid(xs, ys)
    pts = np.column_stack([X.ravel(), Y.ravel()])
    tris = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            a = j * nx + i
            tris += [[a, a + 1, a + nx + 1], [a, a + nx + 1, a + nx]]
    tris = np.array(tris)
    cen = pts[tris].mean(axis=1)
    solid = cen[:, 1] < 0.3 * np.exp(-(((cen[:, 0] - 1.0) / 0.3) ** 2))
    y = pts[:, 1]
    vel = np.column_stack([600 * y * (1 - y), np.zeros_like(y)])
    p = 5000.0 * (2 - pts[:, 0])  # mPa
    disp = np.column_stack([0.01 * y, np.zeros_like(y)])
    return pts, tris, vel, p, disp, solid


def test_fields(outdir):
    pts, tris, vel, p, disp, solid = _channel()
    itf = _bump(0.0)
    paths = [outdir / "fields.png", outdir / "fields.pdf"]
    written, fig = plot_fields(pts, tris, vel, p, disp, paths, interface=itf,
                               solid_mask_triangles=solid, pressure_unit_factor=1e-3,
                               return_figure=True)
    _check_files(written, paths)
    labels = _labels(fig)
    assert {"velocity magnitude |v| [mm/s]", "pressure p [Pa]",
            "displacement magnitude |u| [mm]", "x [mm]", "y [mm]"} <= labels
    # pressure converted from mPa to Pa: colour range 0..10 Pa
    pres_mesh = fig.axes[1].collections[1]
    assert pres_mesh.get_clim()[1] == pytest.approx(10.0)
    # displacement colour range from solid triangles only (fluid mesh motion ignored)
    disp_far = disp + np.column_stack([0.05 * (pts[:, 1] > 0.5), 0 * pts[:, 1]])
    _, fig = plot_fields(pts, tris, vel, p, disp_far, [outdir / "fields2.png"],
                         solid_mask_triangles=solid, return_figure=True)
    solid_nodes = np.unique(tris[solid])
    assert fig.axes[2].collections[1].get_clim()[1] == pytest.approx(
        np.hypot(*disp_far[solid_nodes].T).max())
    with pytest.raises(ValueError, match="triangles"):
        plot_fields(pts, tris + 10**6, vel, p, disp, [outdir / "x.png"])
    with pytest.raises(ValueError, match="solid_mask_triangles"):
        plot_fields(pts, tris, vel, p, disp, [outdir / "x.png"], solid_mask_triangles=solid[:-1])


# --------------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"samples": np.zeros((10, 3))}, "expected 2 columns"),
        ({"weights": np.ones(9)}, "does not match"),
        ({"weights": np.r_[-1.0, np.ones(9)]}, "negative"),
        ({"weights": np.r_[np.nan, np.ones(9)]}, "NaN"),
        ({"samples": np.r_[[[np.nan, 0.0]], np.ones((9, 2))]}, "NaN"),
        ({"names": ["E"]}, "names"),
        ({"paths": ["out.xyz"]}, "unsupported output format"),
        ({"bounds": ((800, 100), (-0.8, 0.5))}, "lo < hi"),
        ({"levels": (0.5, 1.5)}, r"\(0, 1\)"),
        ({"map": (1.0, 2.0, 3.0)}, "map"),
        ({"prior_pdfs": (lambda x: np.ones(3), None)}, "returned shape"),
        ({"gaussian": ((0, 0), [[1, 2], [2, 1]])}, "positive definite"),
    ],
)
def test_joint_rejects_bad_inputs(tmp_path, kwargs, match):
    rng = np.random.default_rng(0)
    args = {"samples": rng.normal(size=(10, 2)) * [100, 0.1] + [400, 0],
            "weights": np.ones(10), "names": NAMES, "units": UNITS,
            "paths": [tmp_path / "j.png"]}
    args.update({k: v for k, v in kwargs.items() if k in args})
    extra = {k: v for k, v in kwargs.items() if k not in args}
    if isinstance(args["paths"][0], str):
        args["paths"] = [tmp_path / args["paths"][0]]
    with pytest.raises(ValueError, match=match):
        plot_joint_posterior(args["samples"], args["weights"], args["names"], args["units"],
                             args["paths"], **extra)


def test_other_functions_reject_bad_inputs(tmp_path):
    x = np.random.default_rng(0).normal(size=(20, 3))
    out = [tmp_path / "x.png"]
    with pytest.raises(ValueError, match="negative"):
        plot_marginals_1d(x, -np.ones(20), ["a", "b", "c"], ["-"] * 3, out)
    with pytest.raises(ValueError, match="units"):
        plot_pair_marginals(x, None, ["a", "b", "c"], ["-"] * 2, out)
    with pytest.raises(ValueError, match="values"):
        plot_parallel_axes(x, np.ones(19), ["a", "b", "c"], ["-"] * 3, out)
    with pytest.raises(ValueError, match="non-negative"):
        plot_parallel_axes(x, -np.ones(20), ["a", "b", "c"], ["-"] * 3, out)
    with pytest.raises(ValueError, match="expected 2 columns"):
        plot_particles(x, None, ["a", "b"], ["-"] * 2, out)
    with pytest.raises(ValueError, match="reference"):
        plot_interfaces(np.zeros((5, 3)), None, None, out)
    with pytest.raises(ValueError, match="values"):
        plot_interface_residual(np.zeros((5, 2)), np.r_[np.nan, np.zeros(4)], out)
    with pytest.raises(ValueError, match="n_train"):
        plot_gp_convergence([10, 20], [1.0], None, out)
    with pytest.raises(ValueError, match="effective sample size"):
        weighted_kde(x, np.r_[1.0, np.zeros(19)])


def test_degenerate_cloud_skips_kde_with_warning(tmp_path):
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.normal(400, 50, 200), np.full(200, 0.3)])
    with pytest.raises(ValueError, match="zero spread"):
        weighted_kde(x)
    with pytest.raises(ValueError, match="collinear"):
        weighted_kde(np.column_stack([x[:, 0], 2 * x[:, 0] + 1]))
    with pytest.warns(UserWarning, match="KDE"):
        _, fig = plot_joint_posterior(x, None, NAMES, UNITS, [tmp_path / "degenerate.png"],
                                      return_figure=True)
    texts = {t.get_text() for ax in fig.axes if ax.get_legend()
             for t in ax.get_legend().get_texts()}
    assert not any(t.startswith("KDE HPD") for t in texts)


def test_the_rounds_figure_shows_the_best_identified_pair():
    """In the heterogeneous study E1 and nu1 (the first two parameters) are not
    identified; the rounds figure must show the pair the data pin down best, relative
    to the box, not the first two."""
    from bayescalib.inference.parameters import ParameterSpace
    from bayescalib.stages.figures import _shown_pair

    params = [{"name": n, "prior": {"type": "uniform", "lo": lo, "hi": hi}, "bounds": [lo, hi]}
              for n, lo, hi in (("E1", 100.0, 1200.0), ("nu1", -0.8, 0.45),
                                ("E2", 100.0, 1200.0), ("nu2", -0.8, 0.45))]
    params.append({"name": "V", "uncertain": True, "prior": {"type": "uniform", "lo": 0.0,
                   "hi": 110.0}, "bounds": [0.0, 110.0]})
    space = ParameterSpace.from_config(params)
    assert _shown_pair(space) == [0, 1]
    # posterior sd: E1 and nu1 at their prior sd, E2 and nu2 narrow, V narrowest (uncertain)
    sd = [305.0, 0.36, 49.0, 0.22, 1.0]
    assert _shown_pair(space, sd) == [2, 3]


def test_the_joint_figure_draws_its_contours_at_the_summarys_credible_levels():
    """posterior.levels reaches the joint figure through posterior.json's intervals,
    so the contours and the reported intervals use the same levels."""
    from bayescalib.stages.figures import _levels

    post = {"intervals": {"E": {"0.8": [1, 2], "0.5": [1, 2], "0.95": [0, 3]},
                          "nu": {"0.8": [0, 1], "0.5": [0, 1], "0.95": [0, 1]}}}
    assert _levels(post) == (0.5, 0.8, 0.95)


def test_the_rounds_figure_marks_the_random_check_points_apart_from_the_acquired_ones(tmp_path):
    """A round's batch holds acquisition picks and random check points
    (``next.kind``); the figure draws them with their own legend entries, so a reader
    sees which solves tested the surrogate without its own choice."""
    from bayescalib.plotting.rounds import plot_rounds

    rng = np.random.default_rng(0)
    draws = [rng.normal(size=(50, 2)) for _ in range(2)]
    design = rng.uniform(-3, 3, size=(12, 2))
    batch = rng.uniform(-3, 3, size=(4, 2))
    args = (draws, design, [8, 12], [batch, None], [None, 0.1], [None, 0.5], NAMES, UNITS,
            [tmp_path / "rounds.png"])
    kw = {"bounds": [[-3, 3], [-3, 3]], "shift_tol": 0.2, "gp_tol": 1.0, "converged": False}
    _, fig = plot_rounds(*args, **kw, batch_kinds=[["acquired"] * 3 + ["check"], None],
                         return_figure=True)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "chosen for next round" in labels
    assert "random check point, next round" in labels
    lines = {ln.get_label(): ln for ln in fig.axes[0].get_lines()}
    assert len(lines["chosen for next round"].get_xdata()) == 3
    np.testing.assert_array_equal(lines["random check point, next round"].get_xdata(),
                                  batch[3:, 0])
    _, fig = plot_rounds(*args, **kw, return_figure=True)   # no kinds: all acquired
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "random check point, next round" not in labels
    with pytest.raises(ValueError, match="4 batch points but 3 kinds"):
        plot_rounds(*args, **kw, batch_kinds=[["check"] * 3, None])
    # a check round: every point of the batch is a posterior draw of the posterior check
    _, fig = plot_rounds(*args, **kw, batch_kinds=[["posterior_check"] * 4, None],
                         return_figure=True)
    lines = {ln.get_label(): ln for ln in fig.axes[0].get_lines()}
    assert "chosen for next round" not in lines
    np.testing.assert_array_equal(lines["posterior check's draws, next round"].get_xdata(),
                                  batch[:, 0])
    # boundary points of the failed region: their own marker, not counted as acquired
    _, fig = plot_rounds(*args, **kw, batch_kinds=[["acquired"] * 2 + ["boundary"] * 2, None],
                         return_figure=True)
    lines = {ln.get_label(): ln for ln in fig.axes[0].get_lines()}
    assert len(lines["chosen for next round"].get_xdata()) == 2
    np.testing.assert_array_equal(
        lines["boundary of the failed region, next round"].get_xdata(), batch[2:, 0])


def test_the_rounds_figure_shows_the_posterior_check_and_one_legend_for_all_panels(tmp_path):
    """A check round's draws appear only in a later panel, yet the legend (in the first)
    names them; the checks' panel draws the posterior check's log-weight sd where it was
    judged (filled: confirmed) and says that the trust check's tolerance then decides
    nothing."""
    from bayescalib.plotting.rounds import plot_rounds

    rng = np.random.default_rng(1)
    draws = [rng.normal(size=(50, 2)) for _ in range(3)]
    design = rng.uniform(-3, 3, size=(16, 2))
    batch = rng.uniform(-3, 3, size=(4, 2))
    _, fig = plot_rounds(
        draws, design, [8, 12, 16], [batch, batch, None], [None, 0.3, 0.1],
        [None, 2.0, 0.4], NAMES, UNITS, [tmp_path / "rounds.png"], bounds=[[-3, 3], [-3, 3]],
        shift_tol=0.2, gp_tol=1.0, converged=True,
        batch_kinds=[["acquired"] * 4, ["posterior_check"] * 4, None],
        posterior_check=[None, None, {"log_weight_sd": 0.13, "confirmed": True}],
        return_figure=True)
    legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "posterior check's draws, next round" in legend
    checks_ax = fig.axes[-1]
    lines = {ln.get_label(): ln for ln in checks_ax.get_lines()}
    confirmed = lines["posterior check of the round before: log-weight sd [nats], confirmed"]
    np.testing.assert_array_equal(confirmed.get_xdata(), [2])
    np.testing.assert_allclose(confirmed.get_ydata(), [0.13])
    assert any("the posterior check decides" in label for label in lines)


def test_the_checks_panel_tells_undecided_and_superseded_looks_from_refuted_ones(tmp_path):
    """A sequential check's looks in the stop-rule panel: an undecided look (its next look
    follows) and a superseded one (stopped, the posterior moved) are not drawn as NOT
    confirmed; a refuted one is."""
    from bayescalib.plotting.rounds import plot_rounds

    rng = np.random.default_rng(2)
    draws = [rng.normal(size=(50, 2)) for _ in range(4)]
    design = rng.uniform(-3, 3, size=(16, 2))
    batch = rng.uniform(-3, 3, size=(4, 2))
    looks = [None, {"log_weight_sd": 0.3, "confirmed": False, "decision": "continue"},
             {"log_weight_sd": 0.25, "confirmed": False, "decision": "superseded"},
             {"log_weight_sd": 1.5, "confirmed": False, "decision": "refuted"}]
    _, fig = plot_rounds(
        draws, design, [8, 12, 16, 20], [batch, batch, batch, None], [None, 0.3, 0.3, 0.1],
        [None, 2.0, 0.4, 0.3], NAMES, UNITS, [tmp_path / "rounds.png"],
        bounds=[[-3, 3], [-3, 3]], shift_tol=0.2, gp_tol=1.0, converged=False,
        batch_kinds=[["posterior_check"] * 4] * 3 + [None], posterior_check=looks,
        return_figure=True)
    lines = {ln.get_label(): ln for ln in fig.axes[-1].get_lines()}
    head = "posterior check of the round before: log-weight sd [nats], "
    for verdict, r in (("undecided", 1), ("superseded", 2), ("NOT confirmed", 3)):
        np.testing.assert_array_equal(lines[head + verdict].get_xdata(), [r])


def test_residual_bands_name_the_located_mismatch_and_its_core(tmp_path):
    from bayescalib.plotting.diagnosis import plot_residual_bands

    s = np.linspace(0.0, 1.0, 21)
    pan = {"s": s, "r": 0.01 * np.sin(3 * s), "r_smooth": 0.01 * np.sin(3 * s),
           "sd": np.full(21, 1e-3), "sd_smooth": np.full(21, 5e-4), "c_pw": 1.96,
           "c_sim": 3.0, "c_smooth": 2.8, "label": "load_1"}
    plain = dict(pan)  # the first panel has no located interval, the second has
    shaded = {**pan, "intervals": [[0.2, 0.9]], "cores": [[0.4, 0.7]]}
    _, fig = plot_residual_bands([plain, shaded], [tmp_path / "r.png"], row_titles=["model"],
                              return_figure=True)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "located mismatch" in labels and any(t.startswith("its core") for t in labels)
    _, fig = plot_residual_bands([plain], [tmp_path / "q.png"], row_titles=["model"],
                              return_figure=True)
    assert "located mismatch" not in [t.get_text() for t in fig.axes[0].get_legend().get_texts()]


def test_figure_jobs_forked_from_a_warm_process_share_no_font_objects():
    """The round job server draws a warm-up figure, then forks figure jobs. A mathtext
    layout holds the FreeType font objects it was made with, and they read glyphs from
    an open font file whose offset a forked child shares with its siblings: two figure
    jobs drawing at once read corrupt outlines ("FT_Load_Glyph ... invalid outline",
    "too many hints"; a fresh default study failed this way). A forked child starts with
    an empty layout cache, and concurrent children draw without error (before the fix,
    two children redrawing the warm-up figure 40 times each failed in every run)."""
    import os

    from bayescalib.plotting import style

    style.warm_up()
    (cache,) = style._SHARED_LAYOUTS
    assert cache.cache_info().currsize > 0
    r, w = os.pipe()
    pids = []
    for _ in range(2):
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the child reports through its exit code
            code = 0
            try:
                os.close(r)
                empty = style._SHARED_LAYOUTS[0].cache_info().currsize == 0
                os.write(w, b"1" if empty else b"0")
                for _ in range(40):
                    style.warm_up()
            except BaseException:  # noqa: BLE001
                code = 1
            os._exit(code)
        pids.append(pid)
    os.close(w)
    codes = [os.waitstatus_to_exitcode(os.waitpid(p, 0)[1]) for p in pids]
    flags = os.read(r, 8)
    os.close(r)
    assert flags == b"11", "a forked child inherited the parent's mathtext layouts"
    assert codes == [0, 0], "a forked child failed to draw (FreeType on a shared font file)"
