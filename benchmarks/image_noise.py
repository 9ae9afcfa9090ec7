"""Calibration and power of the diagnosis's predictive check when the observations come
from images (issue 15): false-alarm rate on a null truth and detection rate of a hidden
effect, per noise model of the check's replicates (``diagnose.noise_model``).

Test bed: the analytic stand-in model (``bayescalib.models.analytic``, E = 400 Pa,
nu = 0.3, loadings V = 50 and 100 mm^2/s), optionally with a hidden ``base_slip`` or
``prestrain`` (the magnitudes of ``tests/test_diagnosis_workflow.py``).

* ``images``: the truth of every loading is rendered as the concealed benchmark does
  (``benchmarks/concealed.py``: 5 um pixels, PSF 1 pixel, 4-look speckle, additive noise
  0.05, pre-smoothing 1 pixel, threshold 0.5, specks under 16 pixels removed), written
  as PNG masks and read by the observation stage (``observations.source: files``); the
  check uses nodes one noise lag (5 pixels) apart and estimates the noise, as the
  diagnose stage does.
* ``synthetic``: the model's nodes plus i.i.d. Gaussian coordinate noise of 1 um (the
  ``observations.source: synthetic`` path); the check is given that noise level.

The calibrated posterior is the *exact* posterior of (E, nu) under the study's
likelihood (closest-point measure, ``sigma_N^2`` below; uniform prior on the tests'
box), sampled by importance sampling from its Laplace approximation (the pipeline's
surrogate and SMC are skipped: the predictive check, not the calibration, is what is
measured); ``n_draws`` equal-weight posterior draws are solved and checked with the
stage's defaults (``ell`` 0.05 mm, alpha 0.05, 64 noise replicates per draw). Each
render/seed uses the same images and draws for every noise model.

With ``--pipeline`` every render instead runs the whole workflow (Snakemake: fixed
design of 32 solves, GP surrogate, SMC posterior, diagnose with 16 draws; the study of
``tests/test_imaging.py``), once per noise model (only the diagnose rule re-runs); the
verdict, the selected candidates and the posterior mean are printed too. With the fixed
design the surrogate's posterior can sit far from the exact one (then the check rightly
fires and the verdict says the calibration is off); ``--active`` uses an active design.

Usage::

    PYTHONPATH=src python benchmarks/image_noise.py [--renders 20] [--first-seed 0] [--pipeline [--active]]
        [--cases null@images,base_slip=0.004@images,...,null@synthetic]
        [--noise-models gaussian,bootstrap] [--out results/image_noise]

Prints a Markdown table (rate of 'inadequate' over the renders with a binomial 95 %
interval, and which statistic fired) and writes ``<out>/table.json``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from bayescalib.diagnosis.residuals import predictive_check
from bayescalib.diagnosis.stage import noise_lag, thinned_observations
from bayescalib.geometry.imaging import pixel_grid, render_scan, segment_scan
from bayescalib.geometry.interface import Interface
from bayescalib.inference.likelihood import log_likelihood
from bayescalib.io.observation_store import StoredObservations, read_observations
from bayescalib.io.observations import add_noise, write_mask_png
from bayescalib.models.analytic import interface as analytic
from bayescalib.stages.observe import observe

TRUTH = {"E": 400.0, "nu": 0.3}
FACTORS = (0.5, 1.0)
BOX = np.array([[100.0, 800.0], [-0.8, 0.45]])
PIXEL_SIZE = 0.005
RENDER = {"psf_sigma": 1.0, "looks": 4.0, "noise": 0.05}
SEGMENT = {"smooth": 1.0, "threshold": 0.5, "min_size": 16}
MARGIN = 0.05
SIGMA_N2 = 4.0e-6  # the image study's likelihood (tests/test_imaging.py: IMAGE_STUDY)
SYNTHETIC_NOISE = 0.001
#: default cases: ``<hidden effect>@<observation mode>``, ``null`` = nothing hidden; the
#: test magnitudes (tests/test_diagnosis_workflow.py: base_slip 0.01 mm, prestrain 0.02)
#: and smaller ones, where detection is not certain
CASES = ("null@images,base_slip=0.01@images,base_slip=0.004@images,base_slip=0.003@images,"
         "base_slip=0.002@images,prestrain=0.02@images,prestrain=0.01@images,"
         "prestrain=0.005@images,null@synthetic,base_slip=0.002@synthetic")


def parse_case(case: str) -> tuple[dict, str]:
    """``'base_slip=0.004@images'`` -> ``({'base_slip': 0.004}, 'images')``."""
    effect, mode = case.split("@")
    if mode not in ("images", "synthetic"):
        raise ValueError(f"case {case!r}: mode must be images or synthetic")
    if effect == "null":
        return {}, mode
    name, value = effect.split("=")
    return {name: float(value)}, mode


def curves(params: dict) -> list[Interface]:
    return [Interface.polyline(analytic({**params, "V": 100.0 * f})["current"]) for f in FACTORS]


def observe_images(truth: list[Interface], seed: int, folder: Path):
    rng = np.random.default_rng(seed)
    files = []
    for k, c in enumerate(truth):
        shape, origin = pixel_grid(c.bounds, PIXEL_SIZE, margin=MARGIN, floor=0.0)
        scan = render_scan(c.points, pixel_size=PIXEL_SIZE, origin=origin, shape=shape, rng=rng,
                           **RENDER)
        mask = segment_scan(scan, **SEGMENT)
        path = folder / f"load_{k}.png"
        write_mask_png(path, mask, pixel_size=PIXEL_SIZE, origin=list(origin), units="mm")
        files.append({"path": str(path), "label": f"load_{k}", "load": None, "units": "mm",
                      "pixel_size": PIXEL_SIZE, "origin": list(origin)})
    section = {"source": "files", "files": files, "domain": [[0.0, 2.0], [0.0, 1.0]]}
    observe(section, folder / "observations.h5")
    return section, read_observations(folder / "observations.h5")


def observe_synthetic(truth: list[Interface], seed: int):
    rng = np.random.default_rng(seed)
    snaps = [add_noise(c, SYNTHETIC_NOISE, rng) for c in truth]
    return {"source": "synthetic"}, StoredObservations(snaps, [f"load_{k}" for k in range(len(snaps))],
                                                       [None] * len(snaps))


def _loglik(theta, obs) -> float:
    E, nu = theta
    if not (BOX[0, 0] <= E <= BOX[0, 1] and BOX[1, 0] <= nu <= BOX[1, 1]):
        return -np.inf
    return log_likelihood(curves({"E": E, "nu": nu}), obs, "cpp", SIGMA_N2)


def posterior_draws(obs, n_draws: int, rng: np.random.Generator, n_is: int = 600) -> np.ndarray:
    """Equal-weight draws of the exact posterior of (E, nu): importance sampling from a
    widened Laplace approximation at the maximum, then systematic resampling."""
    from scipy.optimize import minimize

    f = lambda t: -_loglik(t, obs)
    best = minimize(f, np.array([TRUTH["E"], TRUTH["nu"]]), method="Nelder-Mead",
                    options={"xatol": 1e-4, "fatol": 1e-3, "maxiter": 400}).x
    h = np.array([0.5, 0.002])
    H = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            ei, ej = np.eye(2)[i] * h[i], np.eye(2)[j] * h[j]
            H[i, j] = (f(best + ei + ej) - f(best + ei - ej) - f(best - ei + ej)
                       + f(best - ei - ej)) / (4 * h[i] * h[j])
    H = 0.5 * (H + H.T)
    ev = np.linalg.eigvalsh(H) if np.all(np.isfinite(H)) else np.zeros(2)
    if np.any(ev <= 0):  # the maximum on the box's edge or a flat direction
        scale = np.array([5.0, 0.01])  # Pa, -: a few posterior sd of the null study
        H = np.diag(1.0 / scale**2)
    cov = np.linalg.inv(H) * 2.25  # 1.5 x the Laplace sd
    x = rng.multivariate_normal(best, cov, size=n_is)
    logq = -0.5 * np.einsum("ij,jk,ik->i", x - best, np.linalg.inv(cov), x - best)
    logp = np.array([_loglik(t, obs) for t in x])
    w = np.exp(logp - logq - np.max(logp - logq))
    w /= w.sum()
    u = (rng.random() + np.arange(n_draws)) / n_draws
    return x[np.minimum(np.searchsorted(np.cumsum(w), u), n_is - 1)]


def run_case(case: str, seed: int, models: list[str], n_draws: int, work: Path) -> dict:
    hidden, mode = parse_case(case)
    truth = curves({**TRUTH, **hidden})
    if mode == "images":
        folder = work / f"{case.replace('=', '_').replace('@', '_')}_{seed}"
        folder.mkdir(parents=True, exist_ok=True)
        section, obs = observe_images(truth, 1000 + seed, folder)
        sigma = None
    else:
        section, obs = observe_synthetic(truth, 1000 + seed)
        sigma = SYNTHETIC_NOISE
    lag = noise_lag({"noise_lag": None}, section)
    used = thinned_observations(obs, lag)
    X = posterior_draws(obs, n_draws, np.random.default_rng(seed))
    draws = [curves({"E": E, "nu": nu}) for E, nu in X]
    out = {"case": case, "seed": seed, "posterior_mean": X.mean(axis=0).tolist()}
    for m in models:
        chk = predictive_check(used.snapshots, draws, labels=used.labels, sigma=sigma,
                               noise_lag=lag, noise_model=m,
                               rng=np.random.default_rng(seed + 1))
        out[m] = {"adequate": chk.adequate, "p": chk.p_values, "sigma": chk.sigma}
    return out


#: ``--pipeline``: the image study of tests/test_imaging.py (the analytic model, cpp
#: measure, sigma_N = 2 um, 32 fixed design points, SMC) with only the check (no
#: extended calibration)
PIPELINE_STUDY = {
    "study": "image_noise",
    "forward_model": {"type": "python", "time_limit_s": 60,
                      "python": {"function": "bayescalib.models.analytic:interface"},
                      "loadings": {"parameter": "V", "nominal": 100.0, "factors": list(FACTORS)}},
    "parameters": [
        {"name": "E", "unit": "Pa", "target": "E", "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0},
         "bounds": [100.0, 800.0], "ground_truth": 400.0},
        {"name": "nu", "unit": "-", "target": "nu", "prior": {"type": "uniform", "lo": -0.8, "hi": 0.45},
         "bounds": [-0.8, 0.45], "ground_truth": 0.3}],
    "measures": ["cpp"],
    "likelihood": {"sigma_n2": SIGMA_N2},
    "design": {"strategy": "fixed", "n_train": 32, "seed": 1},
    "surrogate": {"restarts": 1},
    "smc": {"n_particles": 500, "n_rej": 3, "zeta": 0.9, "seed": 0},
    "plots": {"n_interface_samples": 2, "formats": ["png"], "dpi": 60, "grid": 20, "fields": False},
    "diagnose": {"enabled": True, "n_draws": 16, "n_extend": 0,
                 "candidates": [{"name": "base_slip", "target": "base_slip", "step": 0.005,
                                 "prior": [0.0, 0.03], "unit": "mm"}]},
}


#: ``--pipeline --active``: an active design instead (solves placed where the posterior
#: lives until the surrogate's posterior has converged)
ACTIVE_DESIGN = {"strategy": "active", "seed": 1,
                 "active": {"n_initial": 32, "batch_size": 8, "max_solves": 96}}


def run_pipeline(case: str, seed: int, models: list[str], work: Path,
                 active: bool = False) -> dict:
    """The whole workflow (Snakemake: observe, design, surrogate, SMC, diagnose) on the
    masks of one render; the diagnose rule alone is re-run for each further noise
    model (its posterior draws' solves are reused)."""
    import subprocess
    import sys

    import yaml

    hidden, mode = parse_case(case)
    if mode != "images":
        raise ValueError("--pipeline runs image cases only")
    folder = work / f"{case.replace('=', '_').replace('@', '_')}_{seed}"
    (folder / "config").mkdir(parents=True, exist_ok=True)
    section, _ = observe_images(curves({**TRUTH, **hidden}), 1000 + seed, folder)
    out = {"case": case, "seed": seed}
    for m in models:
        study = {**PIPELINE_STUDY, "observations": section,
                 "diagnose": {**PIPELINE_STUDY["diagnose"], "noise_model": m},
                 **({"design": ACTIVE_DESIGN} if active else {})}
        (folder / "config" / "config.yaml").write_text(yaml.safe_dump(study))
        proc = subprocess.run([sys.executable, "-m", "snakemake", "-s",
                               str(Path(__file__).resolve().parents[1] / "Snakefile"),
                               "--directory", str(folder), "--cores", "2"],
                              capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"{case} seed {seed}: snakemake failed\n{proc.stderr[-3000:]}")
        d = json.loads((folder / "results" / "image_noise" / "diagnosis" /
                        "diagnosis.json").read_text())
        chk = d["check"]
        if chk["noise_model"]["name"] != m:
            raise RuntimeError(f"diagnosis.json records {chk['noise_model']['name']}, not {m}")
        out[m] = {"adequate": chk["adequate"], "p": chk["p_values"], "sigma": chk["sigma_mm"],
                  "verdict": d["verdict"], "selected": d["attribution"]["selected"],
                  "posterior_mean": d["posterior_mean"],
                  "converged": d["base_calibration"]["converged"]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--renders", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--cases", default=CASES)
    ap.add_argument("--noise-models", default="gaussian,bootstrap")
    ap.add_argument("--n-draws", type=int, default=16)
    ap.add_argument("--out", type=Path, default=Path("results/image_noise"))
    ap.add_argument("--pipeline", action="store_true",
                    help="run the whole workflow per render (surrogate and SMC posterior; "
                         "~1.5 min a render) instead of the exact posterior")
    ap.add_argument("--active", action="store_true",
                    help="--pipeline: active design (ACTIVE_DESIGN) instead of 32 fixed solves")
    a = ap.parse_args()
    models = a.noise_models.split(",")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in a.cases.split(","):
            for seed in range(a.first_seed, a.first_seed + a.renders):
                r = (run_pipeline(case, seed, models, Path(tmp), a.active) if a.pipeline
                     else run_case(case, seed, models, a.n_draws, Path(tmp)))
                rows.append(r)
                print(case, seed, " ".join(
                    f"{m}: {'ok ' if r[m]['adequate'] else 'INADEQUATE'} "
                    f"p=({', '.join(f'{v:.3f}' for v in r[m]['p'].values())})"
                    + (f" [{r[m]['verdict']}; selected {r[m]['selected']}; posterior mean "
                       f"{r[m]['posterior_mean']}; converged {r[m]['converged']}]"
                       if a.pipeline else "") for m in models),
                    flush=True)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "table.json").write_text(json.dumps(rows, indent=1))
    print("\n| case | noise model | renders | flagged | rate | 95 % interval | "
          "fired: chi2 / max / smooth |\n|---|---|---|---|---|---|---|")
    for case in a.cases.split(","):
        rs = [r for r in rows if r["case"] == case]
        for m in models:
            k = sum(not r[m]["adequate"] for r in rs)
            n = len(rs)
            lo, hi = _wilson(k, n)
            fired = [sum(r[m]["p"][s] < 0.05 / 3 for r in rs)
                     for s in ("chi2", "max_abs", "max_abs_smooth")]
            print(f"| {case} | {m} | {n} | {k} | {k / n:.2f} | [{lo:.2f}, {hi:.2f}] | "
                  f"{' / '.join(map(str, fired))} |")


def _wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, c - h), min(1.0, c + h)


if __name__ == "__main__":
    main()
