"""GP surrogate of the log-likelihood (bayescalib.inference.gp) and the convergence study."""

import numpy as np
import pytest

from bayescalib.inference.convergence import convergence_study_function
from bayescalib.inference.design import sobol_design, sobol_test_points
from bayescalib.inference.gp import GPSurrogate, fit_gp, surrogate_settings

BOX = np.array([[100.0, 800.0], [-0.8, 0.5]])


def smooth_loglik(X):
    e = (X[:, 0] - 100) / 700
    n = (X[:, 1] + 0.8) / 1.3
    return -40.0 * ((n - 0.3 - 0.5 * e) ** 2 + 0.5 * (e - 0.4) ** 2) - 3.0


@pytest.fixture(scope="module")
def gp64():
    X = sobol_design(BOX, 64, 0)
    return fit_gp(X, smooth_loglik(X), bounds=BOX, restarts=2, seed=0,
                  kernel="matern32", nugget="fixed", mean="constant", ard=False)


def test_recovers_smooth_function(gp64):
    # 64 Sobol points of a smooth quadratic: the GP mean should be within 1 % of the
    # range of L (~23) at held-out points (observed 0.4 %; Matern 3/2 converges
    # like n^(-3/(2d)) or better for such smooth targets).
    Xt = sobol_test_points(BOX, 64, 100, 0)
    err = gp64.predict(Xt) - smooth_loglik(Xt)
    y = gp64.y_train
    assert np.sqrt(np.mean(err**2)) < 0.01 * (y.max() - y.min())
    # the GP interpolates its training data up to the tiny nugget
    assert np.allclose(gp64.predict(gp64.X_train), y, atol=1e-3 * (y.max() - y.min()))


def test_mean_and_nugget_rules(gp64):
    y = gp64.y_train
    rng_ = y.max() - y.min()
    assert gp64.mean_const == pytest.approx(y.min() - 1.0 * rng_, rel=1e-14)
    assert gp64.nugget == pytest.approx(1e-5 * rng_, rel=1e-14)
    m = gp64.gpy_model()
    assert m.Gaussian_noise.variance.is_fixed
    assert float(m.Gaussian_noise.variance[0]) == pytest.approx(gp64.nugget, rel=1e-14)
    hp = gp64.hyperparameters
    assert hp["mean"] == gp64.mean_const and hp["nugget"] == gp64.nugget
    assert len(hp["lengthscale"]) == 1 and hp["ard"] is False
    # non-default factors
    X = gp64.X_train[:20]
    g2 = fit_gp(X, smooth_loglik(X), bounds=BOX, restarts=1, mean_offset_factor=0.5,
                nugget_factor=1e-3, kernel="matern32", nugget="fixed", mean="constant", ard=False)
    r2 = g2.y_train.max() - g2.y_train.min()
    assert g2.mean_const == pytest.approx(g2.y_train.min() - 0.5 * r2)
    assert g2.nugget == pytest.approx(1e-3 * r2)


def test_fit_maximizes_evidence(gp64):
    # The stored evidence is GPy's at the stored hyperparameters, and the optimum is a
    # local maximum: perturbing the length scale by +-5 % lowers it.
    m = gp64.gpy_model()
    assert float(m.log_likelihood()) == pytest.approx(gp64.log_marginal_likelihood, rel=1e-10)
    base = float(m.log_likelihood())
    for f in (0.95, 1.05):
        m.kern.lengthscale[:] = gp64.lengthscale * f
        assert float(m.log_likelihood()) < base


@pytest.mark.parametrize("ard", [False, True])
def test_fast_predictor_equals_gpy(ard):
    # Same formulas, different round-off: mean to 1e-8 relative to max|mean|. The
    # variance k** - k*^T K^-1 k* is a difference of numbers of size s^2 (the kernel
    # variance), so both implementations carry absolute round-off ~ s^2 * 1e-13; it is
    # compared to 1e-8 * s^2.
    X = sobol_design(BOX, 80, 1)
    gp = fit_gp(X, smooth_loglik(X), bounds=BOX, ard=ard, restarts=1,
                kernel="matern32", nugget="fixed", mean="constant")
    Xt = np.random.default_rng(0).uniform(BOX[:, 0], BOX[:, 1], size=(3000, 2))
    mu, var = gp.predict(Xt, return_var=True)
    mg, vg = gp.gpy_predict(Xt, return_var=True)
    assert np.max(np.abs(mu - mg)) <= 1e-8 * np.max(np.abs(mg))
    assert np.max(np.abs(var - vg)) <= 1e-8 * gp.variance
    assert np.all(var >= 0)
    # chunking and threading change only the BLAS summation order (round-off ~1e-12 here)
    gp.chunk_entries = gp.cpu_chunk_entries = 1000
    gp.threads = 1
    assert np.allclose(gp.predict(Xt), mu, rtol=0, atol=1e-10 * np.max(np.abs(mu)))
    assert len(gp.hyperparameters["lengthscale"]) == (2 if ard else 1)


def test_torch_backend_matches_numpy(gp64):
    # Same algebra in torch (CPU here; CUDA when available): round-off level agreement.
    Xt = sobol_test_points(BOX, 64, 500, 0)
    m1, v1 = gp64.predict(Xt, return_var=True)
    g = GPSurrogate(
        X_train=gp64.X_train, y_train=gp64.y_train, shift=gp64.shift, scale=gp64.scale,
        mean_const=gp64.mean_const, nugget=gp64.nugget, variance=gp64.variance,
        lengthscale=gp64.lengthscale, ard=gp64.ard, chol=gp64.chol, alpha=gp64.alpha,
        device="torch:cpu",
    )
    m2, v2 = g.predict(Xt, return_var=True)
    assert np.max(np.abs(m1 - m2)) <= 1e-10 * np.max(np.abs(m1))
    assert np.max(np.abs(v1 - v2)) <= 1e-10 * gp64.variance


def test_save_load_round_trip(tmp_path, gp64):
    p = tmp_path / "gp.h5"
    gp64.save(p)
    g = GPSurrogate.load(p)
    Xt = sobol_test_points(BOX, 64, 50, 0)
    m1, v1 = gp64.predict(Xt, return_var=True)
    m2, v2 = g.predict(Xt, return_var=True)
    assert np.array_equal(m1, m2) and np.array_equal(v1, v2)  # exact, no re-optimization
    assert g.hyperparameters == gp64.hyperparameters
    assert g.n_train == gp64.n_train and g.n_excluded == gp64.n_excluded
    assert not list(tmp_path.glob(".gp.h5.*"))  # atomic write leaves no temp file


def test_failed_runs_are_excluded():
    X = sobol_design(BOX, 40, 2)
    y = smooth_loglik(X)
    y[[3, 7, 11]] = [np.nan, -np.inf, np.inf]
    gp = fit_gp(X, y, bounds=BOX, restarts=1,
                kernel="matern32", nugget="fixed", mean="constant", ard=False)
    assert gp.n_excluded == 3 and gp.n_train == 37
    ok = np.isfinite(y)
    assert np.array_equal(gp.X_train, X[ok])
    ref = fit_gp(X[ok], y[ok], bounds=BOX, restarts=1,
                 kernel="matern32", nugget="fixed", mean="constant", ard=False)
    assert np.array_equal(ref.predict(X), gp.predict(X))


def test_seeded_fit_is_reproducible():
    X = sobol_design(BOX, 30, 3)
    a = fit_gp(X, smooth_loglik(X), bounds=BOX, restarts=3, seed=5,
               kernel="matern32", nugget="fixed", mean="constant", ard=False)
    b = fit_gp(X, smooth_loglik(X), bounds=BOX, restarts=3, seed=5,
               kernel="matern32", nugget="fixed", mean="constant", ard=False)
    assert a.hyperparameters == b.hyperparameters


def test_loo_closed_form_matches_refits(gp64):
    # alpha_i / [K^-1]_ii equals y_i minus the prediction of the GP refit without point i
    # (same hyperparameters, mean and nugget): agreement to round-off.
    loo = gp64.loo_residuals()
    for i in (0, 17, 40):
        keep = np.arange(gp64.n_train) != i
        g = GPSurrogate(
            X_train=gp64.X_train[keep], y_train=gp64.y_train[keep], shift=gp64.shift,
            scale=gp64.scale, mean_const=gp64.mean_const, nugget=gp64.nugget,
            variance=gp64.variance, lengthscale=gp64.lengthscale, ard=gp64.ard, device="cpu",
        )
        direct = gp64.y_train[i] - g.predict(gp64.X_train[i : i + 1])[0]
        assert loo[i] == pytest.approx(direct, abs=1e-6 * (1 + abs(direct)))


def test_convergence_study_error_decreases():
    # the paper's GP (Matérn 3/2 of L, one length scale, fixed nugget), as a study's
    # surrogate section gives it
    paper = surrogate_settings(kernel="matern32", output="loglik", ard=False, nugget="fixed",
                               restarts=1)
    out = convergence_study_function(smooth_loglik, BOX, [8, 32, 128], n_test=50,
                                     surrogate=paper)
    assert out["n_train"] == [8, 32, 128] and out["n_test"] == 50
    e = out["l2_error"]
    assert e[0] > e[1] > e[2]
    assert out["rel_error"][2] < 0.01
    assert np.allclose(out["rmse"], np.array(e) / np.sqrt(50))
    assert all(v >= 0 for v in out["loo_rmse"])


def test_scg_optimizer_improves_evidence():
    # SCG (the paper's choice in 6D) must end at a higher evidence than its fixed start
    # (s^2 = mean((y - m)^2), l = 0.3), and not far below L-BFGS-B's optimum.
    from bayescalib.inference.gp.fit import _build_gpy

    X = sobol_design(BOX, 32, 4)
    y = smooth_loglik(X)
    scg = fit_gp(X, y, bounds=BOX, optimizer="scg", restarts=1,
                 kernel="matern32", nugget="fixed", mean="constant", ard=False)
    lbfgsb = fit_gp(X, y, bounds=BOX, optimizer="lbfgsb", restarts=1,
                    kernel="matern32", nugget="fixed", mean="constant", ard=False)
    start = _build_gpy(scg.scale_inputs(X), y, scg.mean_const, np.mean((y - scg.mean_const) ** 2),
                       np.array([0.3]), scg.nugget, False)
    assert scg.log_marginal_likelihood > float(start.log_likelihood())
    assert scg.log_marginal_likelihood > lbfgsb.log_marginal_likelihood - 1.0
    with pytest.raises(ValueError, match="optimizer"):
        fit_gp(X, y, optimizer="adam",
               kernel="matern32", nugget="fixed", mean="constant", ard=False)


@pytest.mark.parametrize("kernel", ["matern32", "matern52", "rbf"])
@pytest.mark.parametrize("device", ["cpu", "torch:cpu"])
def test_every_kernel_predicts_as_gpy_does(kernel, device):
    """The fast predictors (NumPy and torch) equal GPy's predict_noiseless for each
    kernel, warped or not, in the GP's own (latent) units: the mean to 1e-6 of its
    largest magnitude, the variance to 1e-6 of the kernel variance (round-off of two
    independent factorizations; the two fast predictors agree with each other closer).
    A nugget of 1e-3 of the range keeps K well conditioned, so that GPy adds no jitter
    of its own (it does near singularity, and then the two would differ by that)."""
    from bayescalib.inference.gp import fit_gp

    rng = np.random.default_rng(3)
    X = rng.uniform(0, 1, (40, 2))
    y = -50.0 * np.sum((X - 0.4) ** 2, axis=1)
    for bound in (None, 0.0):
        gp = fit_gp(X, y, ard=True, restarts=1, kernel=kernel, bound=bound, device=device,
                    bounds=np.array([[0.0, 1.0], [0.0, 1.0]]), nugget_factor=1e-3,
                    nugget="fixed", mean="constant", warp=True)
        Z = rng.uniform(-0.2, 1.2, (300, 2))
        mu, var = gp.predict_latent(Z, return_var=True)
        ref_mu, ref_var = gp.gpy_model().predict_noiseless(gp.scale_inputs(Z))
        assert np.max(np.abs(mu - ref_mu[:, 0])) <= 1e-6 * np.max(np.abs(ref_mu))
        assert np.max(np.abs(var - ref_var[:, 0])) <= 1e-6 * gp.variance
        assert gp.predict(Z).max() <= (np.inf if bound is None else bound)


def test_threaded_prediction_is_bitwise_the_single_threaded_one(gp64):
    """threads > 1 (the SMC of an active round, granted 2 threads) computes the same
    chunks of points, each alone: the predictions, hence the SMC particles, are bitwise
    those of one thread (summary.json must not depend on the job's threads)."""
    rng = np.random.default_rng(3)
    X = BOX[:, 0] + rng.uniform(0.0, 1.0, (9000, 2)) * (BOX[:, 1] - BOX[:, 0])
    single = gp64.predict(X, return_var=True)
    gp64.threads = 2
    try:
        threaded = gp64.predict(X, return_var=True)
    finally:
        gp64.threads = 1
    chunk_rows = gp64.cpu_chunk_entries // gp64.n_train
    assert X.shape[0] > 2 * chunk_rows  # several chunks, so the pool is used
    for a, b in zip(single, threaded, strict=True):
        assert np.array_equal(a, b)


GPU_PROBE = """
import sys
import numpy as np
from bayescalib.inference import gp as surrogate
from bayescalib.inference.gp import predictor
predictor._GPU_MARKERS = ("/nonexistent/gpu-marker",)
assert not surrogate.gpu_possible()
gp = surrogate.fit_gp(np.array([[0.1, 0.2], [0.5, 0.9], [0.8, 0.3], [0.3, 0.6]]),
                      np.array([-1.0, -2.0, -0.5, -1.5]), restarts=1, kernel="matern32",
                      nugget="fixed", mean="constant", ard=False)
print(gp.device, "torch" in sys.modules)
"""


def test_a_machine_without_gpu_devices_does_not_import_torch():
    """device "auto" on a Linux machine with no GPU device nodes or driver files is the
    NumPy path, decided without importing torch (5-7 s per process that loads a
    surrogate); where torch is imported already, it decides as before."""
    import subprocess
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("the device-file check is Linux only")
    proc = subprocess.run([sys.executable, "-c", GPU_PROBE], capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == ["cpu", "False"]


@pytest.mark.parametrize("kernel", ["matern32", "matern52", "rbf"])
@pytest.mark.parametrize("bound", [None, 0.0])
def test_fast_mean_is_the_gp_formula_evaluated_directly(kernel, bound):
    """The SMC's predictor (augmented distance product, kernel rows in preallocated
    arrays) equals m + s^2 k(x*, X) alpha written out with scipy's cdist, in the GP's
    latent units, to 1e-10 of the magnitudes summed, s^2 sum_j |k_j alpha_j| (same
    alpha, so only the distance algebra's round-off differs; the terms of smooth
    kernels' sums cancel by many orders of magnitude, hence that scale)."""
    from scipy.spatial.distance import cdist

    from bayescalib.inference.gp import KERNELS

    rng = np.random.default_rng(7)
    X = BOX[:, 0] + rng.uniform(0.0, 1.0, (50, 2)) * (BOX[:, 1] - BOX[:, 0])
    gp = fit_gp(X, smooth_loglik(X), bounds=BOX, restarts=1, kernel=kernel, bound=bound,
                device="cpu", nugget="fixed", mean="constant", ard=False, warp=True)
    Z = BOX[:, 0] + rng.uniform(-0.1, 1.1, (3000, 2)) * (BOX[:, 1] - BOX[:, 0])
    c = KERNELS[kernel][0]
    t = c * cdist(gp.scale_inputs(Z) / gp.lengthscale, gp.scale_inputs(gp.X_train) / gp.lengthscale)
    f = {"matern32": (1 + t) * np.exp(-t), "matern52": (1 + t + t**2 / 3) * np.exp(-t),
         "rbf": np.exp(-(t**2))}[kernel]
    ref = gp.mean_const + gp.variance * f @ gp.alpha
    scale = gp.variance * np.abs(f) @ np.abs(gp.alpha)
    assert np.all(np.abs(gp.predict_latent(Z) - ref) <= 1e-10 * scale)


def test_predictions_do_not_depend_on_the_calls_before_them(gp64):
    """The kernel rows live in arrays kept between calls (per thread, grown on demand):
    a prediction is bitwise the same whatever was predicted before it (larger and
    smaller batches, a single point, the variance's larger chunks, two threads). (The
    same points in a batch of another size may differ in the last bit: BLAS picks its
    kernel by the row count; so did the predictor before the arrays were kept.)"""
    rng = np.random.default_rng(5)
    X = BOX[:, 0] + rng.uniform(0.0, 1.0, (2500, 2)) * (BOX[:, 1] - BOX[:, 0])
    first = gp64.predict(X)
    for other in (5000, 1, 7, 20000):
        gp64.predict(BOX[:, 0] + rng.uniform(0.0, 1.0, (other, 2)) * (BOX[:, 1] - BOX[:, 0]),
                     return_var=other == 20000)
        assert np.array_equal(gp64.predict(X), first)
    gp64.threads = 2
    try:
        assert np.array_equal(gp64.predict(X), first)
    finally:
        gp64.threads = 1
