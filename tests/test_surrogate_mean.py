"""The misfit-shaped (negative-quadratic) prior mean of the GP surrogate (surrogate.mean;
issue 17).

With the constant mean the surrogate falls to a floor away from the solves, so an active
design can only crawl up a likelihood's slope. The quadratic mean
Phi_m(u) = phi0 + 1/2 |R (u - c)|^2, carried through the GP's output transform and fitted
by the evidence with the kernel, extrapolates toward the mode. These tests state what it
must gain (the mode and curvature of a Gaussian log-likelihood from few points; uphill
extrapolation toward an unseen mode) and what it must keep (the likelihood's bound, the
file format and older files, the fast predictor's agreement with GPy, the gradient of
the evidence).
"""

import h5py
import numpy as np
import pytest

from bayescalib.config import validate
from bayescalib.inference.design import sobol_design
from bayescalib.inference.gp import (
    GPSurrogate,
    fit_from_config,
    fit_gp,
    principal_frame,
    resolve_mean,
)
from bayescalib.inference.gp.fit import _build_gpy
from bayescalib.inference.gp.inputs import frame_extent
from bayescalib.inference.gp.mean import _quadratic_mapping_class

BOX3 = np.array([[0.0, 1.0], [-1.0, 1.0], [10.0, 30.0]])
MODE3 = np.array([0.55, 0.2, 18.0])
#: covariance of the 3D Gaussian: correlated (rho 0.6 between the first two inputs)
SD3 = np.array([0.05, 0.15, 2.0])
CORR3 = np.array([[1.0, 0.6, 0.0], [0.6, 1.0, -0.3], [0.0, -0.3, 1.0]])
COV3 = CORR3 * np.outer(SD3, SD3)
PREC3 = np.linalg.inv(COV3)


def gauss3(X):
    """A Gaussian log-likelihood with bound 0: L = -1/2 (x - m)^T P (x - m)."""
    R = np.atleast_2d(X) - MODE3
    return -0.5 * np.einsum("ij,jk,ik->i", R, PREC3, R)


def _mode_and_hessian(gp):
    """The quadratic mean's centre (user units) and misfit Hessian in user units (linear
    inputs): u = ((x - shift) / scale) V, so d u / d x = diag(1 / scale) V."""
    V = np.eye(gp.dim) if gp.rotation is None else gp.rotation
    x0 = gp.shift + gp.scale * (gp.mean_center @ V.T)
    J = np.diag(1.0 / gp.scale) @ V
    H = J @ gp.mean_factor.T @ gp.mean_factor @ J.T
    return x0, H


@pytest.mark.parametrize("warp", [True, False])
def test_the_quadratic_mean_recovers_the_mode_and_curvature_of_a_gaussian(warp):
    # 24 Sobol points of a correlated 3D Gaussian (misfit up to ~1e3 nats in the box).
    # The misfit is exactly the mean's quadratic (through log1p for the log-misfit GP),
    # so the evidence is largest when the mean carries all of it: the only error left is
    # the optimizer's. Tolerances: the mode within 0.01 posterior sd per parameter and
    # the Hessian within 1 % (relative Frobenius norm); observed ~1e-5 sd and ~1e-5.
    X = sobol_design(BOX3, 24, 0)
    gp = fit_gp(X, gauss3(X), ard=True, bounds=BOX3, bound=0.0, warp=warp,
                mean="quadratic", restarts=2, seed=0, kernel="matern32", nugget="fixed")
    assert gp.mean_function == "quadratic" and gp.warped == warp
    x0, H = _mode_and_hessian(gp)
    assert np.all(np.abs(x0 - MODE3) / SD3 < 0.01)
    assert np.linalg.norm(H - PREC3) / np.linalg.norm(PREC3) < 0.01
    assert 0.0 <= gp.mean_misfit_min < 0.01
    # and so the surrogate is right far from the points: at 3 sd in every direction
    Xt = MODE3 + 3.0 * SD3 * np.array([[1, 1, 1], [-1, 1, -1], [1, -1, 1]])
    assert np.allclose(gp.predict(Xt), gauss3(Xt), atol=0.05)


def test_the_constant_mean_does_not_recover_the_gaussian_from_the_same_points():
    # The control for the test above: the same 24 points, the paper's constant mean.
    # Its error at the mode is far larger (observed ~20 nats) than the quadratic's.
    X = sobol_design(BOX3, 24, 0)
    gp = fit_gp(X, gauss3(X), ard=True, bounds=BOX3, bound=0.0, warp=True,
                mean="constant", restarts=2, seed=0, kernel="matern32", nugget="fixed")
    assert abs(gp.predict(MODE3)[0] - 0.0) > 1.0


MODE_U = np.array([0.9, 0.5, 0.4])
SD_U = np.array([0.1, 0.2, 0.25])


def _unseen_mode_design():
    """A 3D Gaussian in the unit box with its mode at x1 = 0.9; 30 Sobol points with
    x1 <= 0.4 only (the nearest solve 5 sd from the mode along x1)."""
    box = np.array([[0.0, 1.0]] * 3)

    def L(X):
        return -0.5 * np.sum(((np.atleast_2d(X) - MODE_U) / SD_U) ** 2, 1)

    X = sobol_design(np.array([[0.0, 0.4], [0.0, 1.0], [0.0, 1.0]]), 30, 1)
    return box, MODE_U, L, X


@pytest.mark.parametrize("warp", [True, False])
def test_the_quadratic_mean_extrapolates_uphill_toward_an_unseen_mode(warp):
    # The best solve is ~14 nats below the mode. Where the posterior lives (2000 seeded
    # draws of the Gaussian within the box), the quadratic-mean GP is right within
    # 0.05 nats RMS (observed ~1e-12: the shape is exact), predicts the mode within
    # 0.1 nats and has its own maximum within 0.5 sd of it. The constant-mean GP,
    # fitted to the same points, also rises beyond them (long length scales) but without
    # the shape: its RMS error there exceeds 1 nat (observed 1.5 and 3.3).
    box, mode, L, X = _unseen_mode_design()
    y = L(X)
    kw = {"ard": True, "bounds": box, "bound": 0.0, "warp": warp, "restarts": 2, "seed": 0,
          "kernel": "matern32", "nugget": "fixed"}
    quad = fit_gp(X, y, mean="quadratic", **kw)
    const = fit_gp(X, y, mean="constant", **kw)
    assert y.max() < -10.0
    P = mode + SD_U * np.random.default_rng(0).standard_normal((3000, 3))
    P = P[np.all((P >= 0.0) & (P <= 1.0), axis=1)][:2000]
    assert np.sqrt(np.mean((quad.predict(P) - L(P)) ** 2)) < 0.05
    assert abs(quad.predict(mode)[0]) < 0.1
    G = np.random.default_rng(1).uniform(box[:, 0], box[:, 1], size=(20000, 3))
    assert np.all(np.abs(G[np.argmax(quad.predict(G))] - mode) < 0.5 * SD_U)
    assert np.sqrt(np.mean((const.predict(P) - L(P)) ** 2)) > 1.0


@pytest.mark.parametrize("output", ["log_misfit", "loglik"])
def test_the_quadratic_mean_surrogate_never_exceeds_the_bound(output):
    # Data up to the bound (one solve 0.01 sd from the mode, within 1e-3 nats of B = 3):
    # the mean of a GP of L falls from B itself (mean_top == B), and the predictions
    # never exceed B anywhere in the box (4096 Sobol points), at the solves or the mode.
    box, mode, L, X = _unseen_mode_design()
    B = 3.0
    X = np.vstack([X, mode + 0.001])
    y = L(X) + B
    cfg = validate({"surrogate": {"ard": True, "kernel": "matern32", "mean": "quadratic",
                                  "output": output, "frame": "axes", "inputs": "linear"}},
                   "inference", where="test")["surrogate"]
    gp = fit_from_config(X, y, cfg, box, bound=B)
    assert gp.mean_function == "quadratic" and gp.warped == (output == "log_misfit")
    if not gp.warped:
        assert gp.mean_top == B
    G = np.vstack([sobol_design(box, 4096, 3), X, mode])
    assert np.max(gp.predict(G)) <= B
    assert np.max(gp.prior_mean(G) if not gp.warped else B - np.expm1(gp.prior_mean(G))) <= B


@pytest.fixture(scope="module")
def rotated_log_quad():
    """A quadratic-mean surrogate in the principal frame with a log input (E-like), of a
    Gaussian plus a smooth non-quadratic term (so that the kernel part matters)."""
    X = sobol_design(BOX3, 40, 2)
    y = gauss3(X) - 2.0 * np.sin(3.0 * X[:, 0])
    offsets = np.array([np.nan, np.nan, 0.0])
    V = principal_frame(X, y, BOX3, offsets)
    return fit_gp(X, y, ard=True, bounds=BOX3, bound=0.0, warp=True, mean="quadratic",
                  rotation=V, log_offset=offsets, restarts=1, seed=0, device="cpu",
                  kernel="matern32", nugget="fixed")


@pytest.mark.parametrize("device", ["cpu", "torch:cpu"])
def test_the_fast_predictor_equals_gpy_with_the_quadratic_mean(rotated_log_quad, device):
    # Same formulas, different round-off (as for the constant mean): the latent mean to
    # 1e-8 of its largest value, the variance to 1e-8 of the kernel variance. GPy adds a
    # jitter of 1e-8 to the nugget in its inference; with this fit's small kernel
    # variance (the mean carries most of the function) that shifts its prediction by
    # ~1e-6, so the comparison takes the jitter off GPy's nugget.
    gp = rotated_log_quad
    gp.device = device
    gp._cache.clear()
    Xt = np.random.default_rng(1).uniform(BOX3[:, 0], BOX3[:, 1], size=(2000, 3))
    mu, var = gp.predict_latent(Xt, True)
    model = gp.gpy_model()
    assert float(model.log_likelihood()) == pytest.approx(gp.log_marginal_likelihood, rel=1e-8)
    model.Gaussian_noise.variance.unfix()
    model.Gaussian_noise.variance[:] = gp.nugget - 1e-8
    mg, vg = model.predict_noiseless(gp.scale_inputs(Xt))
    assert np.max(np.abs(mu - mg[:, 0])) <= 1e-8 * np.max(np.abs(mg))
    assert np.max(np.abs(var - vg[:, 0])) <= 1e-8 * gp.variance
    gp.device = "cpu"
    gp._cache.clear()


def test_a_quadratic_mean_surrogate_round_trips_through_its_file(rotated_log_quad, tmp_path):
    gp = rotated_log_quad
    p = tmp_path / "gp.h5"
    gp.save(p)
    g = GPSurrogate.load(p, device="cpu")
    Xt = np.random.default_rng(2).uniform(BOX3[:, 0], BOX3[:, 1], size=(500, 3))
    m1, v1 = gp.predict(Xt, return_var=True)
    m2, v2 = g.predict(Xt, return_var=True)
    assert np.array_equal(m1, m2) and np.array_equal(v1, v2)  # exact, no re-optimization
    assert g.hyperparameters == gp.hyperparameters
    assert g.hyperparameters["mean_function"] == "quadratic"


def test_a_surrogate_file_of_format_version_2_still_reads_as_a_constant_mean(tmp_path):
    # Version 2 had no mean_function attribute: such a file is a constant-mean surrogate
    # and predicts as it did. A file of a newer version than this reader is refused.
    X = sobol_design(BOX3, 20, 0)
    gp = fit_gp(X, gauss3(X), ard=True, bounds=BOX3, bound=0.0, restarts=1, device="cpu",
                kernel="matern32", nugget="fixed", mean="constant", warp=True)
    p = tmp_path / "v2.h5"
    gp.save(p)
    with h5py.File(p, "a") as f:
        f.attrs["format_version"] = 2
        del f.attrs["mean_function"]
    g = GPSurrogate.load(p, device="cpu")
    assert g.mean_function == "constant"
    assert np.array_equal(g.predict(X), gp.predict(X))
    with h5py.File(p, "a") as f:
        f.attrs["format_version"] = 4
    with pytest.raises(ValueError, match="version 4"):
        GPSurrogate.load(p)


@pytest.mark.parametrize("warp", [True, False])
def test_the_evidence_gradient_of_the_mean_parameters_is_exact(warp):
    # GPy's finite-difference check of the analytic gradients (mean and kernel),
    # away from any optimum, in a rotated frame with correlations in R.
    X = sobol_design(BOX3, 30, 4)
    U = (X - BOX3[:, 0]) / (BOX3[:, 1] - BOX3[:, 0])
    y = gauss3(X) - 3.0 * np.sin(4.0 * U[:, 0])
    y = np.log1p(-np.minimum(y, 0.0)) if warp else y
    V, _ = np.linalg.qr(np.random.default_rng(1).standard_normal((3, 3)))
    lo, hi = frame_extent(V, 3)
    ext = hi - lo
    R = np.triu(np.full((3, 3), 0.7)) + np.diag([2.0, 3.0, 1.5])
    mapping = _quadratic_mapping_class()(3, lo - 0.5 * ext, hi + 0.5 * ext, ext,
                                         float("nan") if warp else 0.0, warp,
                                         np.array([0.2, 0.4, 0.6]), R, 0.3)
    model = _build_gpy(U @ V, y, 0.0, 1.0, np.full(3, 0.3), 1e-4, True, "matern32", mapping)
    assert model.checkgrad(tolerance=1e-4)


def test_auto_is_the_quadratic_mean_from_three_parameters_on_and_the_default_is_constant():
    assert [resolve_mean("auto", d) for d in (1, 2, 3, 7)] == \
        ["constant", "constant", "quadratic", "quadratic"]
    assert resolve_mean("constant", 7) == "constant" and resolve_mean("quadratic", 2) == "quadratic"
    cfg = validate({"surrogate": {"mean": "auto"}}, "inference", where="test")["surrogate"]
    assert validate({"surrogate": {}}, "inference", where="test")["surrogate"]["mean"] == \
        "constant"  # the schema's default (docs/bench_active.md says why)
    X = sobol_design(BOX3, 20, 0)
    assert fit_from_config(X, gauss3(X), {**cfg, "kernel": "matern32", "output": "log_misfit",
                                          "frame": "axes", "inputs": "linear"},
                           BOX3, bound=0.0).mean_function == "quadratic"
