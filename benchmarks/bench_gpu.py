"""CPU and GPU side by side: the GP predictor, the SMC on it, and the RKHS distance.

What it measures (one row per device and case; ``--cases``, default all):

* ``predict2d``, ``predict7d``: :meth:`GPSurrogate.predict` (the mean, what the SMC
  calls) on 1e6 (2D) / 2e5 (7D) prior draws with the training sets of the SMC cases
  below; median wall of ``--repeats`` calls after one warm-up call, throughput, and
  the largest difference of the mean (over all points) and of the variance (on the
  first ``--var-points`` points) against the NumPy path.
* ``smc2d``, ``smc7d``: :func:`run_smc` on the surrogate with the paper's settings
  (2D: banana log-likelihood of ``bench_smc.py``, 1000 Sobol training points,
  N = 5000, n_rej = 20, zeta = 0.995; 7D: 2000 points, N = 10000, n_rej = 30,
  zeta = 0.998), the same generator seed on every device: wall, tempering steps,
  evaluations, log evidence, posterior mean. The devices' predictions differ in
  round-off, so the Metropolis decisions part after some steps and the runs are
  equal in distribution, not bitwise: the agreement column gives the largest
  difference of the posterior means in posterior standard deviations (of the
  reference row) and the difference of the log evidence, both of the order of the
  Monte Carlo error. A CPU run longer than ``--cpu-budget`` seconds is stopped after
  the step that passes it and its wall extrapolated (time per step x the steps of a
  complete run; marked ``~``): the 7D run takes minutes on a CPU.
* ``round7d``, ``round7d_outputs``: the heterogeneous study's round
  (``config/heterogeneous.yaml``): SMC with its rounds' settings (``design.active.smc``:
  N = 2000, n_rej = 10, zeta = 0.99, :data:`ROUND_SMC`) on a 7-D surrogate of its largest
  design (512 solves): ``round7d`` the GP of the log-likelihood (the ``smc7d`` problem),
  ``round7d_outputs`` the output emulator (``surrogate.target: outputs``) of
  ``bench_active.py``'s ``hetero7d`` model, 11 coordinate GPs; on a torch device it runs
  twice, the coordinate GPs batched in one pass (the library's way,
  :class:`~bayescalib.inference.gp.predictor.StackedGPs`) and one after the other
  (``<device> (per GP)``). Issue 38's aim: under 15 s a round on the GPU.
* ``rkhs3d``: :func:`rkhs_squared` of two concentric triangulated spheres of 20480
  triangles each (icosphere level 5, sigma_W = 0.05 on the unit sphere, default
  truncation, float64); ``cpu`` is the NumPy backend, ``torch:cpu`` and ``cuda`` the
  torch one (``torch:cpu`` is added to this case where torch is installed: at this size
  the pipeline's ``backend="auto"`` runs torch on a CPU); agreement: relative difference
  of the three terms and of D^2.

The surrogates are built directly from fixed hyperparameters, not fitted with GPy
(the GPU machine has no GPy; the timings do not depend on how the hyperparameters were
found): box-scaled inputs, Matérn 3/2, the paper's constant mean
m = min(L) - (max(L) - min(L)) and nugget 1e-5 (max(L) - min(L)), kernel variance the
mean square of L - m, and one length scale (on every input) chosen from a short grid by
the closed-form leave-one-out error. The header of each case prints the surrogate's
error against the analytic log-likelihood on held-out prior draws and in the posterior
region (L > max L - 10), so a reader sees that the surrogate is sane.

Devices (``--devices``, default ``cpu,cuda``): ``cpu`` is the NumPy path
(``GPSurrogate(device="cpu")``, ``threads = --threads``), ``cuda`` the torch path on the
GPU (skipped, with a line saying so, where torch sees none), ``torch:cpu`` the torch path
on the CPU (``torch.set_num_threads(--threads)``), to exercise it without a GPU.

Run (on a lent GPU machine, from the repository root; about 6-8 minutes: each CPU SMC
row stops after ``--cpu-budget`` seconds)::

    PYTHONPATH=src python3 benchmarks/bench_gpu.py --threads 16 --cpu-budget 40 --out bench_gpu.json

(``--threads 16`` for the CPU rows on all cores); ``--quick`` is a seconds-long run
at small sizes (N 500, 200 training points, 1280 triangles) for tests.

Reading the table: one markdown table per case; ``wall s`` the median wall time
(``~``: extrapolated), ``speed-up`` the NumPy ``cpu`` row's wall divided by the row's
(above 1: faster than NumPy on the CPU), ``agreement`` the difference from the
reference row (the NumPy ``cpu`` row where run). ``--out`` writes the rows as JSON.

Earlier figures (one H200 machine, 16 cores; issue 38): the CUDA predictor agrees with
NumPy to 2e-8; SMC 2D 18.5 s on one CPU thread, 20.9 s on 16, 1.4 s on CUDA; SMC 7D
20 s on CUDA vs more than 380 s on 16 CPU threads; RKHS 3D 20480 triangles 0.27 s on
CUDA vs 0.98 s on the CPU.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import statistics
import sys
import time
import types
from pathlib import Path

import numpy as np

_HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(_HERE))  # bench_smc: the problems of the SMC cases
sys.path.insert(0, str(_HERE.parent / "tests"))  # _interface_shapes: the icospheres

try:  # bayescalib.config (imported with the GP package) needs PyYAML only to read files
    import yaml  # noqa: F401
    _YAML_STUB = False
except ImportError:  # pragma: no cover - the GPU machine may lack it; no YAML is read here
    _stub = types.ModuleType("yaml")
    _stub.YAMLError = Exception
    sys.modules["yaml"] = _stub
    _YAML_STUB = True

from _interface_shapes import icosphere
from bench_smc import BOX_7D, _loglik_7d_factory, _space, banana_2d

from bayescalib.inference.design import sobol_design
from bayescalib.inference.gp.kernels import kernel_matrix
from bayescalib.inference.gp.predictor import GPSurrogate
from bayescalib.inference.smc import run_smc
from bayescalib.measures.currents import rkhs_squared

CASES = ("predict2d", "predict7d", "smc2d", "smc7d", "round7d", "round7d_outputs", "rkhs3d")
#: the heterogeneous study's rounds (config/heterogeneous.yaml, design.active.smc:
#: N, n_rej, zeta; a test holds them equal) and its largest design (max_solves)
ROUND_SMC = (2000, 10, 0.99)
ROUND_N_TRAIN = 512

#: per problem: box, analytic log-likelihood factory, training points, SMC settings
#: (N, n_rej, zeta), prediction points; ``quick`` the sizes of ``--quick``
PROBLEMS = {
    "2d": {"n_train": 1000, "smc": (5000, 20, 0.995), "n_predict": 1_000_000},
    "7d": {"n_train": 2000, "smc": (10000, 30, 0.998), "n_predict": 200_000},
    "round": {"n_train": ROUND_N_TRAIN, "smc": ROUND_SMC},
}
QUICK = {
    "2d": {"n_train": 200, "smc": (500, 20, 0.995), "n_predict": 20_000},
    "7d": {"n_train": 300, "smc": (500, 10, 0.99), "n_predict": 5_000},
    "round": {"n_train": 64, "smc": (300, 3, 0.9)},
}
#: icosphere refinement level of the RKHS case (20 * 4**level triangles)
RKHS_LEVEL, RKHS_LEVEL_QUICK = 5, 3
RKHS_SIGMA_W = 0.05

#: candidate length scales (box-scaled inputs) of the leave-one-out choice
LENGTHSCALE_GRID = (0.2, 0.35, 0.6, 1.0, 1.7, 3.0)


class _Stop(Exception):
    pass


# ---------------------------------------------------------------------------
# environment
# ---------------------------------------------------------------------------


def _torch_or_none():
    try:
        import torch
    except ImportError:
        return None
    return torch


def environment(threads: int) -> dict:
    """Host, CPU count, library versions and the GPU torch sees (printed and returned)."""
    import scipy

    torch = _torch_or_none()
    info = {
        "host": platform.node(),
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "load_average": os.getloadavg() if hasattr(os, "getloadavg") else None,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "torch": None if torch is None else torch.__version__,
        "cuda_available": bool(torch is not None and torch.cuda.is_available()),
        "gpu": None,
        "threads": threads,
        "yaml_stub": _YAML_STUB,
    }
    if info["cuda_available"]:
        info["gpu"] = torch.cuda.get_device_name(0)
    print(f"host: {info['host']} ({info['cpu']}), {info['cpu_count']} CPUs, "
          f"load average {info['load_average']}")
    print(f"numpy {info['numpy']}, scipy {info['scipy']}, torch {info['torch']}, "
          f"torch.cuda.is_available() = {info['cuda_available']}")
    print(f"GPU: {info['gpu']}" if info["gpu"] else "no GPU: GPU columns not measured")
    print(f"threads: NumPy predictor GPSurrogate.threads = {threads}, torch CPU threads = "
          f"{threads if torch is not None else 'n/a'} (OPENBLAS_NUM_THREADS = "
          f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')})")
    if _YAML_STUB:
        print("note: PyYAML is absent; a stand-in module lets bayescalib.config import "
              "(nothing here reads YAML)")
    return info


def resolve_devices(spec: str, info: dict) -> list[str]:
    """The devices of ``--devices`` that can run here; a line for each one skipped."""
    out = []
    for dev in [d.strip() for d in spec.split(",") if d.strip()]:
        if dev != "cpu" and info["torch"] is None:
            print(f"device {dev}: skipped (torch is not installed)")
        elif dev.startswith("cuda") and not info["cuda_available"]:
            print(f"device {dev}: skipped (no CUDA GPU visible to torch)")
        elif dev == "cpu" or dev == "torch:cpu" or dev.startswith("cuda"):
            out.append(dev)
        else:
            raise SystemExit(f"unknown device {dev!r}; use cpu, torch:cpu or cuda[:i]")
    return out


def _sync(device: str) -> None:
    if device.startswith("cuda"):  # also "cuda (per GP)"
        _torch_or_none().cuda.synchronize()


# ---------------------------------------------------------------------------
# surrogates from fixed hyperparameters
# ---------------------------------------------------------------------------


def problem(name: str):
    """(space, analytic log-likelihood) of the ``2d`` or ``7d`` case of ``bench_smc.py``."""
    if name == "2d":
        return _space(np.array([[100.0, 800.0], [-0.8, 0.5]]), False), banana_2d
    return _space(BOX_7D, True), _loglik_7d_factory()


def _loo_rmse(U: np.ndarray, r: np.ndarray, variance: float, ell: float,
              nugget: float, kernel: str = "matern32") -> float:
    """Closed-form leave-one-out RMSE of a GP with zero mean on residuals r (eq. 5.12 of
    Rasmussen & Williams 2006); inf where the Cholesky factorization fails."""
    from scipy.linalg import cho_factor, cho_solve

    K = kernel_matrix(U, U, variance, np.array([ell]), kernel)
    K[np.diag_indices_from(K)] += nugget
    try:
        cf = cho_factor(K, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return math.inf
    Kinv = cho_solve(cf, np.eye(len(r)), check_finite=False)
    return float(np.sqrt(np.mean((Kinv @ r / np.diag(Kinv)) ** 2)))


def fixed_gp(X: np.ndarray, y: np.ndarray, bounds: np.ndarray, *, kernel: str,
             mean: float, nugget: float) -> tuple[GPSurrogate, float, float]:
    """A GP of y at X with fixed hyperparameters: box-scaled inputs, constant mean
    ``mean``, kernel variance the mean square of y - mean, the given nugget, and one length
    scale (on every input) from :data:`LENGTHSCALE_GRID` by the closed-form leave-one-out
    error. Returns the GP (NumPy device), the length scale and its LOO RMSE."""
    shift, scale = bounds[:, 0].copy(), bounds[:, 1] - bounds[:, 0]
    U = (X - shift) / scale
    variance = float(np.mean((y - mean) ** 2))
    loo = {ell: _loo_rmse(U, y - mean, variance, ell, nugget, kernel)
           for ell in LENGTHSCALE_GRID}
    ell = min(loo, key=loo.get)
    gp = GPSurrogate(X_train=X, y_train=y, shift=shift, scale=scale, mean_const=mean,
                     nugget=nugget, variance=variance, lengthscale=np.full(X.shape[1], ell),
                     ard=True, kernel=kernel, device="cpu")
    return gp, ell, loo[ell]


def build_surrogate(space, loglik, n_train: int, rng: np.random.Generator) -> GPSurrogate:
    """A GP of ``loglik`` with fixed hyperparameters (module docstring); prints the
    length scale and the errors on held-out prior draws.

    Parameters
    ----------
    space
        The :class:`~bayescalib.inference.parameters.ParameterSpace` (box and prior).
    loglik
        The analytic log-likelihood, (M, d) -> (M,).
    n_train
        Sobol training points in the box.
    rng
        Generator of the held-out draws.

    Returns
    -------
    GPSurrogate
        On the NumPy device (``device="cpu"``); :func:`on_device` moves it.
    """
    bounds = np.asarray(space.bounds, float)
    X = sobol_design(bounds, n_train, 0)
    y = loglik(X)
    y_range = float(y.max() - y.min())
    t0 = time.perf_counter()
    gp, ell, loo = fixed_gp(X, y, bounds, kernel="matern32", mean=float(y.min() - y_range),
                            nugget=1e-5 * y_range)
    print(f"surrogate: d = {space.dim}, n_train = {n_train}, Matérn 3/2, length scale {ell} "
          f"(LOO RMSE {loo:.3g} nats; grid {list(LENGTHSCALE_GRID)}), range of L "
          f"{y_range:.4g} nats, built in {time.perf_counter() - t0:.2f} s")
    _print_errors(gp.predict, loglik, space, rng)
    return gp


def _print_errors(predict, loglik, space, rng: np.random.Generator) -> None:
    """The surrogate's error against the analytic log-likelihood on held-out prior draws
    and in the posterior region (L > max L - 10)."""
    Xh = space.sample_prior(4000, rng)
    yh = loglik(Xh)
    err = predict(Xh) - yh
    post = yh > yh.max() - 10.0
    post_txt = (f"{np.sqrt(np.mean(err[post] ** 2)):.3g} nats RMSE on the {int(post.sum())} "
                f"with L > max L - 10" if post.any() else "no draw with L > max L - 10")
    print(f"surrogate vs analytic L on 4000 held-out prior draws: RMSE "
          f"{np.sqrt(np.mean(err ** 2)):.3g} nats, max |error| {np.max(np.abs(err)):.3g} nats; "
          f"{post_txt}")


#: hyperparameters of the output emulator of ``round7d_outputs`` at full size, as the
#: library fits them (``--fit-emulator``, which needs GPy, writes the file)
EMULATOR_FIT = _HERE / "data" / "round7d_emulator.json"


def _h7_design(n_train: int):
    """(bounds, design X, outputs U in noise units, data y in noise units) of ``hetero7d``."""
    import bench_active as ba

    bounds = ba.H7_BOUNDS
    X = sobol_design(bounds, n_train, 0)
    noise = np.random.default_rng(ba.H7_NOISE_SEED).standard_normal(ba.H7_K)
    y = (ba.h7_model(ba.H7_TRUTH)[0] + ba.H7_SIGMA * noise) / ba.H7_SIGMA
    return bounds, X, _h7_outputs(X), y


def fit_emulator(n_train: int, path: Path) -> None:
    """Fit the output emulator of ``round7d_outputs`` with the library
    (:func:`~bayescalib.inference.emulator.fit_output_emulator`: ARD Matérn 5/2, log
    inputs by evidence, fitted nuggets; GPy) and write each coordinate GP's
    hyperparameters to ``path`` for machines without GPy."""
    from bayescalib.inference.emulator import fit_output_emulator

    bounds, X, U, _ = _h7_design(n_train)
    t0 = time.perf_counter()
    em = fit_output_emulator(X, U, bounds)
    coords = [{"variance": float(g.variance), "lengthscale": g.lengthscale.tolist(),
               "nugget": float(g.nugget), "shift": g.shift.tolist(),
               "scale": g.scale.tolist(),
               "log_offset": None if g.log_offset is None else
               [None if not math.isfinite(v) else float(v) for v in g.log_offset]}
              for g in em.components]
    path.write_text(json.dumps({"n_train": n_train, "components": len(coords),
                                "coordinates": coords}, indent=1) + "\n")
    print(f"emulator fitted with the library in {time.perf_counter() - t0:.1f} s "
          f"({len(coords)} coordinates), hyperparameters written to {path}")


def build_emulator(n_train: int, rng: np.random.Generator):
    """The output emulator of ``bench_active.py``'s ``hetero7d`` model (40 interface
    displacements of a 7-parameter model, the heterogeneous study's shape), as
    ``surrogate.target: outputs`` fits it (:mod:`bayescalib.inference.emulator`:
    principal outputs in noise units, one Matérn 5/2 GP per coordinate). The coordinate
    GPs take the library's fitted hyperparameters from :data:`EMULATOR_FIT` when it
    holds this ``n_train``; otherwise (``--quick``) one length scale each by
    :func:`fixed_gp` (zero mean, nugget 1e-6 noise units squared). Returns (space,
    emulated likelihood)."""
    from bayescalib.inference.emulator import (
        EmulatedLikelihood,
        OutputEmulator,
        principal_outputs,
    )

    bounds, X, U, y = _h7_design(n_train)
    t0 = time.perf_counter()
    mean, basis, coords, discarded = principal_outputs(U)
    fit = json.loads(EMULATOR_FIT.read_text()) if EMULATOR_FIT.exists() else None
    if fit is not None and fit["n_train"] == n_train and fit["components"] == len(coords.T):
        # zero prior mean: the coordinates are centred (their sign, which an SVD leaves
        # free, does not matter then)
        comps = [GPSurrogate(X_train=X, y_train=coords[:, j], shift=np.array(h["shift"]),
                             scale=np.array(h["scale"]), mean_const=0.0, nugget=h["nugget"],
                             variance=h["variance"], lengthscale=np.array(h["lengthscale"]),
                             ard=True, kernel="matern52", device="cpu",
                             log_offset=None if h["log_offset"] is None else np.array(
                                 [np.nan if v is None else v for v in h["log_offset"]]))
                 for j, h in enumerate(fit["coordinates"])]
        how = f"the library's fit ({EMULATOR_FIT.name})"
    else:
        comps = [fixed_gp(X, coords[:, j], bounds, kernel="matern52", mean=0.0,
                          nugget=1e-6)[0] for j in range(basis.shape[0])]
        how = f"one length scale each by LOO ({[float(g.lengthscale[0]) for g in comps]})"
    lik = EmulatedLikelihood(OutputEmulator(mean=mean, basis=basis, components=comps,
                                            discarded=discarded, n_train=n_train), y)
    print(f"emulator: hetero7d, n_train = {n_train}, {len(comps)} coordinate GPs "
          f"(Matérn 5/2; hyperparameters: {how}), discarded {discarded:.3g}, built in "
          f"{time.perf_counter() - t0:.2f} s")

    def loglik(Z):
        r = _h7_outputs(Z) - y
        return -0.5 * np.sum(r * r, axis=1)

    space = _space(bounds, True)  # q, the inflow, is the uncertain condition
    _print_errors(lik.predict, loglik, space, rng)
    return space, lik


def _h7_outputs(Z: np.ndarray) -> np.ndarray:
    import bench_active as ba

    return ba.h7_model(Z) / ba.H7_SIGMA


def emulator_on_device(lik, device: str, threads: int, stack: bool = True):
    """The same emulated likelihood with its coordinate GPs on another device; ``stack``
    False evaluates them one after the other on a torch device (for comparison)."""
    from bayescalib.inference.emulator import EmulatedLikelihood

    em = dataclasses.replace(lik.emulator, components=[
        on_device(g, device, threads) for g in lik.emulator.components], stack=stack)
    return EmulatedLikelihood(em, lik.y, offset=lik.offset)


def on_device(gp: GPSurrogate, device: str, threads: int) -> GPSurrogate:
    """The same surrogate (same factors, no refactorization) on another device."""
    return dataclasses.replace(gp, device=device, threads=threads, _cache={})


# ---------------------------------------------------------------------------
# cases
# ---------------------------------------------------------------------------


def _row(case, device, wall, **kw) -> dict:
    return {"case": case, "device": device, "wall_s": wall, **kw}


def case_predict(case, gp, space, n_points, devices, repeats, var_points, threads, seed):
    """Time ``predict`` (the mean) on ``n_points`` prior draws per device.

    Parameters
    ----------
    case, gp, space
        Case name, the NumPy surrogate, its parameter space.
    n_points, repeats
        Prior draws per call; timed calls (after one warm-up call).
    devices
        Devices in order; the first is the reference of the agreement.
    var_points
        The variance is compared on the first ``var_points`` draws (its triangular
        solve costs n_train times the mean's work per point).
    threads, seed
        NumPy predictor threads; seed of the draws.

    Returns
    -------
    list of dict
        One row per device (``wall_s``, ``runs``, ``evals_per_s``, ``rel_dmean``, ...).
    """
    X = space.sample_prior(n_points, np.random.default_rng(seed))
    Xv = X[:var_points]
    rows, ref = [], None
    for dev in devices:
        g = on_device(gp, dev, threads)
        g.predict(X[: min(len(X), 2000)])  # warm-up: caches, CUDA context, kernels
        _sync(dev)
        walls = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            mean = g.predict(X)
            _sync(dev)
            walls.append(time.perf_counter() - t0)
        _, var = g.predict(Xv, return_var=True)
        wall = statistics.median(walls)
        row = _row(case, dev, wall, runs=walls, n_points=n_points, n_train=gp.n_train,
                   evals_per_s=n_points / wall)
        if ref is None:
            ref = (mean, var)
            row["agreement"] = "reference"
        else:
            dm = float(np.max(np.abs(mean - ref[0])))
            dv = float(np.max(np.abs(var - ref[1])))
            row.update(max_abs_dmean=dm, rel_dmean=dm / float(np.max(np.abs(ref[0]))),
                       max_abs_dvar=dv, rel_dvar=dv / max(float(np.max(ref[1])), 1e-300))
            row["agreement"] = (f"mean {dm:.2e} abs ({row['rel_dmean']:.1e} of max abs mean), "
                                f"var {dv:.2e} abs ({row['rel_dvar']:.1e} of max var)")
        print(f"  {dev:10s} predict {n_points} points: median {wall:.3f} s "
              f"(runs {', '.join(f'{t:.3f}' for t in walls)}), {n_points / wall:.3g} points/s; "
              f"{row['agreement']}")
        rows.append(row)
    return rows


def case_smc(case, make, space, smc_settings, devices, seed, cpu_budget):
    """``run_smc`` on the surrogate per device, one seed for all.

    Parameters
    ----------
    case, space
        Case name, the parameter space (prior).
    make
        device -> the surrogate on that device (``loglik``, ``predict``); a device
        ``"<dev> (per GP)"`` is ``<dev>`` with an emulator's coordinate GPs one after the
        other.
    smc_settings
        (N, n_rej, zeta).
    devices, seed
        Devices in order; the generator seed of every run.
    cpu_budget
        A run on a CPU device (``cpu``, ``torch:cpu``) stops after the step that passes
        this many seconds (0: no limit); :func:`smc_agreement` extrapolates its wall.

    Returns
    -------
    list of dict
        One row per device (``wall_s``, ``steps``, ``evals``, ``log_evidence``,
        ``post_mean``, ``post_sd``, ``agreement``, ...).
    """
    N, n_rej, zeta = smc_settings
    print(f"  SMC: N = {N}, n_rej = {n_rej}, zeta = {zeta}, seed {seed}")
    rows = []
    for dev in devices:
        g = make(dev)
        g.predict(space.sample_prior(100, np.random.default_rng(1)))  # warm-up
        _sync(dev)
        steps: list[float] = []
        t0 = time.perf_counter()
        budget = cpu_budget if (cpu_budget > 0 and not dev.startswith("cuda")) else math.inf

        def stop_after_budget(info, steps=steps, t0=t0, budget=budget):
            steps.append(time.perf_counter() - t0)
            if steps[-1] > budget:
                raise _Stop

        res = None
        try:
            res = run_smc(g.loglik, space, n_particles=N, n_rej=n_rej, zeta=zeta,
                          rng=np.random.default_rng(seed), callback=stop_after_budget)
        except _Stop:
            pass
        wall = time.perf_counter() - t0
        row = _row(case, dev, wall, complete=res is not None, steps_done=len(steps))
        if res is not None:
            W = res.weights
            mu = W @ res.particles
            sd = np.sqrt(np.maximum(W @ (res.particles - mu) ** 2, 0.0))
            row.update(steps=res.n_steps, evals=res.n_loglik_evals,
                       log_evidence=float(res.log_evidence), post_mean=mu.tolist(),
                       post_sd=sd.tolist(), evals_per_s=res.n_loglik_evals / wall)
            print(f"  {dev:10s} {wall:8.2f} s, {res.n_steps} steps, {res.n_loglik_evals} "
                  f"evaluations ({res.n_loglik_evals / wall:.3g}/s), log Z = "
                  f"{res.log_evidence:.4f}, posterior mean {np.round(mu, 4).tolist()}")
        else:
            row["s_per_step"] = wall / len(steps)
            print(f"  {dev:10s} stopped after {len(steps)} steps, {wall:.2f} s "
                  f"(--cpu-budget {cpu_budget:g} s): {wall / len(steps):.3f} s per step")
        rows.append(row)
    return smc_agreement(rows)


def smc_agreement(rows: list[dict]) -> list[dict]:
    """Fill in the agreement of the SMC rows with the reference (the complete NumPy ``cpu``
    run, else the first complete run) and the extrapolated wall of the stopped runs
    (seconds per step x the reference's steps)."""
    complete = [r for r in rows if r["complete"]]
    ref = next((r for r in complete if r["device"] == "cpu"), complete[0] if complete else None)
    for r in rows:
        if not r["complete"]:
            if ref is None:
                r["agreement"] = (f"n/a (stopped after {r['steps_done']} steps, "
                                  f"{r['s_per_step']:.3f} s/step; no complete run to "
                                  "extrapolate to)")
                r["wall_s"] = math.nan
                continue
            r["wall_s"] = r["s_per_step"] * ref["steps"]
            r["extrapolated"] = True
            r["agreement"] = (f"n/a (stopped after {r['steps_done']} of {ref['steps']} steps; "
                              f"wall = {r['s_per_step']:.3f} s/step x {ref['steps']})")
        elif r is ref:
            r["agreement"] = "reference"
        else:
            sd = np.maximum(np.asarray(ref["post_sd"]), 1e-300)
            dmu = np.abs(np.asarray(r["post_mean"]) - np.asarray(ref["post_mean"])) / sd
            r["max_dmean_sd"] = float(dmu.max())
            r["dlog_evidence"] = r["log_evidence"] - ref["log_evidence"]
            r["agreement"] = (f"posterior mean {r['max_dmean_sd']:.3f} sd, log Z "
                              f"{r['dlog_evidence']:+.4f}; steps {r['steps']} vs {ref['steps']} "
                              "(equal in distribution; bitwise only by chance)")
    return rows


def case_round(case, sizes, devices, seed, cpu_budget, threads):
    """The heterogeneous study's round: SMC with its rounds' settings
    (:data:`ROUND_SMC`) on the 7-D surrogate of the last round (``n_train`` solves).

    ``round7d``: the GP of the log-likelihood (``surrogate.target: loglik``, the
    ``smc7d`` problem); ``round7d_outputs``: the output emulator of ``hetero7d``
    (``surrogate.target: outputs``, :func:`build_emulator`), on torch devices also with its
    coordinate GPs one after the other (rows ``<device> (per GP)``) beside the batched pass.

    Returns
    -------
    list of dict
        :func:`case_smc`'s rows.
    """
    rng = np.random.default_rng(seed + 7)
    if case == "round7d":
        space, loglik = problem("7d")
        gp = build_surrogate(space, loglik, sizes["n_train"], rng)
        return case_smc(case, lambda dev: on_device(gp, dev, threads), space, sizes["smc"],
                        devices, seed, cpu_budget)
    space, lik = build_emulator(sizes["n_train"], rng)
    devs = []
    for d in devices:
        devs += [d] if d == "cpu" else [d, f"{d} (per GP)"]

    def make(dev):
        base = dev.removesuffix(" (per GP)")
        return emulator_on_device(lik, base, threads, stack=base == dev)

    return case_smc(case, make, space, sizes["smc"], devs, seed, cpu_budget)


def case_rkhs(level, devices, repeats, threads):
    """``rkhs_squared`` of two concentric icospheres per device.

    Parameters
    ----------
    level
        Icosphere refinement (20 * 4**level triangles per sphere).
    devices
        ``cpu`` runs the NumPy backend, the others torch; the first is the reference.
    repeats, threads
        Timed calls; torch CPU threads.

    Returns
    -------
    list of dict
        One row per device (``wall_s``, ``terms``, ``d2``, ``rel_terms``, ``rel_d2``).
    """
    s1, s2 = icosphere(1.0, level), icosphere(1.02, level)
    x, a, y, b = s1.centres, s1.current, s2.centres, s2.current
    print(f"  two spheres of {len(x)} and {len(y)} triangles, sigma_W = {RKHS_SIGMA_W}, "
          "default truncation, float64")
    if "cpu" in devices and "torch:cpu" not in devices and _torch_or_none() is not None:
        devices = [d for d in devices if d == "cpu"] + ["torch:cpu"] + \
            [d for d in devices if d != "cpu"]
        print("  torch:cpu added: at this size the pipeline's rkhs_squared (backend 'auto') "
              "runs torch on a CPU")
    rows, ref = [], None
    for dev in devices:
        if dev == "cpu":
            kw = {"backend": "numpy"}
        else:
            kw = {"backend": "torch", "device": dev.removeprefix("torch:")}

        def f(kw=kw):
            return rkhs_squared(x, a, y, b, RKHS_SIGMA_W, dtype="float64", threads=threads, **kw)

        if dev != "cpu":
            f()  # warm-up (CUDA context and kernels; the NumPy path has none)
        walls, val = [], None
        for _ in range(repeats):
            t0 = time.perf_counter()
            val = f()
            _sync(dev)
            walls.append(time.perf_counter() - t0)
        wall = statistics.median(walls)
        d2 = val[0] - 2.0 * val[1] + val[2]
        row = _row("rkhs3d", dev, wall, runs=walls, n1=len(x), n2=len(y), terms=list(val),
                   d2=d2)
        if ref is None:
            ref = row
            row["agreement"] = "reference"
        else:
            rel = max(abs(v - w) / abs(w) for v, w in zip(val, ref["terms"], strict=True))
            rd2 = abs(d2 - ref["d2"]) / abs(ref["d2"])
            row.update(rel_terms=rel, rel_d2=rd2)
            row["agreement"] = f"terms {rel:.1e} relative, D^2 {rd2:.1e} relative"
        print(f"  {dev:10s} median {wall:.3f} s (runs {', '.join(f'{t:.3f}' for t in walls)}), "
              f"D^2 = {d2:.10g}; {row['agreement']}")
        rows.append(row)
    return rows


# ---------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------


def table(rows: list[dict]) -> str:
    """One markdown table per case: device, median wall, speed-up vs the NumPy cpu row,
    agreement."""
    out = []
    for case in dict.fromkeys(r["case"] for r in rows):
        rs = [r for r in rows if r["case"] == case]
        cpu = next((r for r in rs if r["device"] == "cpu"), None)
        out += [f"\n### {case}\n", "| device | wall s | speed-up vs NumPy cpu | agreement |",
                "|---|---:|---:|---|"]
        for r in rs:
            wall = r["wall_s"]
            tilde = "~" if r.get("extrapolated") else ""
            wall_txt = "n/a" if not math.isfinite(wall) else f"{tilde}{wall:.3f}"
            ratio = "n/a"
            if cpu is not None and math.isfinite(cpu["wall_s"]) and math.isfinite(wall):
                approx = "~" if r.get("extrapolated") or cpu.get("extrapolated") else ""
                ratio = f"{approx}{cpu['wall_s'] / wall:.2f}"
            out.append(f"| {r['device']} | {wall_txt} | {ratio} | {r['agreement']} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> list[dict]:
    """Run the benchmark and print the table.

    Parameters
    ----------
    argv
        Command-line arguments (None: ``sys.argv``); ``--help`` lists them.

    Returns
    -------
    list of dict
        The rows of the table (also written by ``--out``).
    """
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default=",".join(CASES), help=f"subset of {','.join(CASES)}")
    ap.add_argument("--devices", default="cpu,cuda",
                    help="cpu (NumPy), torch:cpu, cuda (skipped where absent)")
    ap.add_argument("--threads", type=int, default=1,
                    help="GPSurrogate.threads of the NumPy rows and torch CPU threads")
    ap.add_argument("--repeats", type=int, default=3, help="timed calls of predict and rkhs")
    ap.add_argument("--var-points", type=int, default=5000,
                    help="points of the variance comparison (predict cases)")
    ap.add_argument("--cpu-budget", type=float, default=90.0,
                    help="stop a CPU SMC run after the step passing this many seconds and "
                         "extrapolate its wall (0: no limit)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the SMC and prior draws")
    ap.add_argument("--quick", action="store_true", help="small sizes, a few seconds")
    ap.add_argument("--out", default=None, help="write the rows (and the host) as JSON")
    ap.add_argument("--fit-emulator", action="store_true",
                    help=f"fit round7d_outputs' emulator with the library (GPy) and write "
                         f"{EMULATOR_FIT.relative_to(_HERE.parent)}, then exit")
    a = ap.parse_args(argv)
    if a.fit_emulator:
        fit_emulator(ROUND_N_TRAIN, EMULATOR_FIT)
        return []
    cases = [c.strip() for c in a.cases.split(",") if c.strip()]
    unknown = set(cases) - set(CASES)
    if unknown:
        raise SystemExit(f"unknown cases {sorted(unknown)}; choose from {list(CASES)}")

    info = environment(a.threads)
    devices = resolve_devices(a.devices, info)
    if any(d != "cpu" for d in devices):
        _torch_or_none().set_num_threads(a.threads)
    sizes = QUICK if a.quick else PROBLEMS
    repeats = 1 if a.quick else a.repeats
    print(f"devices: {devices}; cases: {cases}; {'quick' if a.quick else 'full'} sizes")

    rows: list[dict] = []
    gps: dict[str, GPSurrogate] = {}
    t_all = time.perf_counter()
    for case in cases:
        print(f"\n=== {case}")
        if case == "rkhs3d":
            rows += case_rkhs(RKHS_LEVEL_QUICK if a.quick else RKHS_LEVEL, devices, repeats,
                              a.threads)
            continue
        if case.startswith("round"):
            rows += case_round(case, sizes["round"], devices, a.seed, a.cpu_budget, a.threads)
            continue
        dim = case[-2:]
        space, loglik = problem(dim)
        if dim not in gps:
            gps[dim] = build_surrogate(space, loglik, sizes[dim]["n_train"],
                                       np.random.default_rng(a.seed + 7))
        if case.startswith("predict"):
            rows += case_predict(case, gps[dim], space, sizes[dim]["n_predict"], devices,
                                 repeats, min(a.var_points, sizes[dim]["n_predict"]),
                                 a.threads, a.seed)
        else:
            rows += case_smc(case, lambda dev, g=gps[dim]: on_device(g, dev, a.threads), space,
                             sizes[dim]["smc"], devices, a.seed, a.cpu_budget)
    print(f"\ntotal {time.perf_counter() - t_all:.1f} s")
    print(table(rows))
    if a.out:
        clean = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                  for k, v in r.items()} for r in rows]
        Path(a.out).write_text(json.dumps({"environment": info, "rows": clean}, indent=1,
                                          default=float))
        print(f"\nrows written to {a.out}")
    return rows


if __name__ == "__main__":
    main()
