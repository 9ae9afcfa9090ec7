"""The GP convergence study (paper Sec. 4.3) before and after the convergence stage fitted
the study's own surrogate (issue 37, item 3).

Before, ``stages.convergence`` unpacked the ``surrogate`` section by hand and fitted one
GP of its own: Matérn 3/2 (the fit's default, not the study's ``kernel``), a constant
mean, the schema's nugget, no likelihood bound (so no warped output), no principal
frame, no log inputs, on the raw log-likelihood values. After, each n fits the study's
surrogate (:func:`bayescalib.inference.gp.fit_from_config` with the whole section and the
table's bound), so the figure measures the GP that the calibration uses.

Both are fitted here to the same training table of a finished study (its first n Sobol
points) and scored against the same held-out Sobol points by the same function
(:func:`bayescalib.inference.convergence.convergence_study`). The "after" column is
recomputed here and compared with the study's own ``convergence.json`` (they must agree:
same code, same data).

Usage (after ``snakemake --cores 2 --configfile config/gp_convergence.yaml``)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/gp_convergence_ab.py \
        --config config/gp_convergence.yaml [--out docs/figures/gp_convergence_ab.png]

Prints one row per n: relative L2 error and RMSE (nats) of both GPs, their ratio, the
study surrogate's choices, and each fit's time.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from bayescalib.config import load_yaml, merge_layers
from bayescalib.inference.convergence import convergence_study
from bayescalib.inference.gp import fit_from_config
from bayescalib.inference.gp.fit import fit_gp
from bayescalib.inference.gp.selection import resolve_ard
from bayescalib.inference.parameters import ParameterSpace
from bayescalib.stages.files import read_stage_file
from bayescalib.stages.surrogate import loglik_bound, loglik_training_set
from bayescalib.study import Study


def before_fit(surrogate: dict, bounds: np.ndarray):
    """The GP the convergence stage fitted before issue 37 (commit adf0c3a^):
    ``fit_gp`` with its defaults then (Matérn 3/2, constant mean) and the section's
    nugget and optimizer settings; no bound, frame or log inputs."""
    def fit(X, L):
        return fit_gp(X, L, kernel="matern32", nugget=surrogate["nugget"], mean="constant",
                      ard=resolve_ard(surrogate["ard"], bounds.shape[0]),
                      optimizer=surrogate["optimizer"], restarts=surrogate["restarts"],
                      seed=surrogate["seed"], bounds=bounds,
                      mean_offset_factor=surrogate["mean_offset_factor"],
                      nugget_factor=surrogate["nugget_factor"],
                      nugget_floor=surrogate["nugget_floor"])
    return fit


def timed(fit):
    """``fit`` that records each call's wall time in ``timed.seconds``."""
    seconds: list[float] = []

    def wrapped(X, L):
        t0 = time.perf_counter()
        gp = fit(X, L)
        seconds.append(time.perf_counter() - t0)
        return gp
    wrapped.seconds = seconds
    return wrapped


def _choices(h: dict) -> str:
    """The discrete choices in a surrogate's hyperparameters, in words."""
    return ", ".join([
        str(h["kernel"]), f"output {h['output']}", f"mean {h['mean_function']}",
        f"nugget {h['nugget_mode']}", "ard" if h["ard"] else "isotropic",
        "principal frame" if h.get("input_rotation") is not None else "box frame",
        "log inputs" if h.get("input_log_offset") is not None else "linear inputs"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="config/gp_convergence.yaml")
    ap.add_argument("--measure", default=None, help="default: the study's first measure")
    ap.add_argument("--out", default=None, help="figure (png/pdf) of both curves")
    args = ap.parse_args(argv)

    study = Study(merge_layers([load_yaml("config/config.yaml"), load_yaml(args.config)]))
    cfg = study.config
    measure = args.measure or study.measures[0]
    root = Path(study.root) / measure
    tab = read_stage_file(root / "training.h5", "training table")
    tr = tab["is_train"].astype(bool)
    bounds = ParameterSpace.from_config(cfg["parameters"]).bounds
    X_raw, L_raw = tab["X"][tr], tab["loglik"][tr]
    X, L = loglik_training_set(tab)
    bound = loglik_bound(tab, tr)
    X_test, L_test = tab["X"][~tr], tab["loglik"][~tr]
    n_list = list(cfg["convergence"]["n_train"])
    surrogate = dict(cfg["surrogate"])

    old = timed(before_fit(surrogate, bounds))
    new = timed(lambda Xn, Ln: fit_from_config(Xn, Ln, surrogate, bounds, bound=bound))
    res_old = convergence_study(X_raw, L_raw, X_test, L_test, n_list, old)
    res_new = convergence_study(X, L, X_test, L_test, n_list, new)

    recorded = json.loads((root / "convergence.json").read_text())
    same = np.allclose(recorded["rel_error"], res_new["rel_error"], rtol=1e-9, atol=0.0)

    print(f"study {cfg['study']}, measure {measure}: {int(tr.sum())} training points, "
          f"{res_new['n_test']} held-out ({res_new['n_test_failed']} failed), bound {bound:.4g}")
    print(f"{'n':>5} {'rel L2 before':>14} {'rel L2 after':>13} {'after/before':>13} "
          f"{'RMSE before':>12} {'RMSE after':>11} {'fit s before':>13} {'fit s after':>12}"
          "  study surrogate's choices")
    for i, n in enumerate(n_list):
        ro, rn = res_old["rel_error"][i], res_new["rel_error"][i]
        print(f"{n:5d} {ro:14.4g} {rn:13.4g} {rn / ro:13.3f} {res_old['rmse'][i]:12.4g} "
              f"{res_new['rmse'][i]:11.4g} {old.seconds[i]:13.2f} {new.seconds[i]:12.2f}  "
              f"{_choices(res_new['surrogate'][i])}")
    print(f"the study's convergence.json equals the 'after' column: {same}")

    if args.out:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(5.0, 3.6))
        ax.loglog(n_list, res_old["rel_error"], "s--", label="before: Matérn 3/2, constant mean")
        ax.loglog(n_list, res_new["rel_error"], "o-", label="after: the study's surrogate")
        ax.set_xlabel("training points n")
        ax.set_ylabel("relative L2 error at held-out points")
        ax.set_title(f"GP convergence ({cfg['study']}, {measure})", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.out, dpi=120)
        print(f"figure: {args.out}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
