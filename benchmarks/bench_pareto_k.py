"""The Pareto-k test of the posterior check (bayescalib.inference.importance) at 50-256
draws: false refusals of a right posterior, detection of a wrong one, under candidate
rules for when k is judged.

The real posterior is pi, S draws of a surrogate posterior q are "solved" (L = log pi up
to a constant) and checked; coordinates are in units of pi's (main lobe's) sd. Cases:

* ``right``: q = pi = N(0, I_d); the surrogate's log-likelihood mu = L + eps h(x) with
  ``noise`` (h independent per draw) or ``smooth`` (the random smooth function of
  benchmarks/bench_sd_ratio.py: 50 random Fourier features of length scale 1 with the
  Hermite parts of degree <= 2 taken out, unit sd under q) or ``bounded`` (the same 50
  features with only their mean under q taken out, unit sd: |h| is bounded, so the
  weights are bounded and their true Pareto shape is negative), log-weight sd eps nats.
  The check should confirm. For ``noise`` and ``bounded`` any k refusal is false. The
  ``smooth`` error is right in its moments (to first order in eps) but not in its tails:
  the subtracted polynomial grows where the features stay bounded, so in 1-D pi has up to
  several times q's mass beyond 3 sd (printed per function at the end); a k refusal
  there is partly a true one;
* ``narrow s``: q = N(0, diag(s^2, 1, ..)), pi = N(0, I): too narrow in one direction
  (weights' true Pareto shape 1 - s^2: 0.75 for s = 0.5, 0.51 for s = 0.7);
* ``lobe w at a``: pi = (1 - w) N(0, I) + w N(a e_1, I), q = N(0, I) (the main lobe):
  q misses a lobe of mass w = 0.2 at a = 3 or 4 sd;
* ``t3``: pi has a Student-t marginal with 3 degrees of freedom (scale 1) in the first
  direction, N(0, 1) in the others; q = N(0, diag(s^2, 1, ..)) with s = 1 (the t's
  scale: q fitted to pi's body) or s = sqrt(3) (pi's sd).
  The weights' tail is infinite-variance in both (w ~ exp(x^2 / (2 s^2)) |x|^-4).

For each cell (case, d, S; ``--reps`` seeded replicates) the table gives the medians of
the log-weight sd, the ESS fraction, S times the largest normalized weight (``S wmax``)
and k from PSIS's tail (``-``: not estimated; k90 its 90th percentile), and the rate of
refusal by the k test alone and by the whole check (sd_tol 0.2, the other criteria at
their defaults) under the rules:

* ``psis``: k >= 0.7 refuses, k fitted to PSIS's tail M = ceil(min(S/5, 3 sqrt S))
  (``importance_check`` before issue 17), estimated from S >= 50 draws; every other rule
  but ``adopted`` and ``M ..`` judges this k;
* ``adopted``: k >= 0.7 refuses, k as ``importance_check`` now estimates it, from the
  longer tail M = ceil(min(0.3 S, 3 sqrt S)) (the same as PSIS's from S = 225 on);
* ``psis-S``: k >= min(1 - 1/log10(S), 0.7) (Vehtari et al. 2024, eq. 13: the sample-size
  dependent threshold of PSIS, 0.41 at S = 50, 0.45 at 64, 0.53 at 128, 0.58 at 256);
* ``wmax c``: k judged (against 0.7) only when S max_s W_s >= c (W normalized weights;
  c = 2, 3): with the largest weight below c times the mean, no draw carries more than
  c / S of any estimate and ESS >= S / c;
* ``lsd l``: k judged only when the log-weights' sd is at least l nats (0.3, 0.5);
* ``tail m``: k judged only when the tail M = ceil(min(S/5, 3 sqrt S)) has >= m weights
  (a larger ``MIN_TAIL``: m = 20 judges from S = 100, m = 26 from S = 128);
* ``k t``: a higher threshold, k >= t refuses (t = 0.9, 1.0);
* ``M f S<=c rtS`` / ``M f S``: k estimated (still from S >= 50 only) from a longer tail,
  M = ceil(min(f S, c sqrt S)) or ceil(f S) weights (PSIS: f = 0.2, c = 3), against 0.7;
* ``never``: k not judged (the other criteria alone).

Run::

    python benchmarks/bench_pareto_k.py [--reps 500] [--dims 1,7] [--draws 50,64,128,256]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_sd_ratio import _smooth

SD_TOL = 0.2
K_REL = 0.7

CASES: list[tuple[str, dict]] = (
    [(f"right, {kind} {eps:g} nats", {"case": "right", "kind": kind, "eps": eps})
     for kind in ("smooth", "bounded", "noise") for eps in (0.1, 0.2, 0.4, 0.6)]
    + [(f"narrow {s:g}, 1 dir", {"case": "narrow", "s": s}) for s in (0.5, 0.7)]
    + [(f"lobe 0.2 at {a:g} sd", {"case": "lobe", "w": 0.2, "a": a}) for a in (4.0, 3.0)]
    + [("t3, q sd 1 (t's scale)", {"case": "t3", "s": 1.0}),
       ("t3, q sd 1.73 (t's sd)", {"case": "t3", "s": math.sqrt(3.0)})])


class Bounded:
    """A random smooth bounded function on R^d: the 50 random Fourier features of
    ``bench_sd_ratio.Smooth`` (same seeds) less their mean under N(0, I), scaled to unit
    sd under N(0, I); |h| <= 2 sqrt(2 J) / scale everywhere."""

    def __init__(self, d: int, j: int) -> None:
        sm = _smooth(d, j)
        self.om, self.b, self.a0 = sm.om, sm.b, sm.a0
        self.scale = 1.0
        rng = np.random.default_rng([1, d, j, 7])
        self.scale = float(np.std(self(rng.standard_normal((50_000, d)))))

    def __call__(self, X: np.ndarray) -> np.ndarray:
        c = math.sqrt(2.0 / self.b.size)
        return (c * np.cos(X @ self.om.T + self.b).sum(axis=1) - self.a0) / self.scale


_BOUNDED: dict[tuple[int, int], Bounded] = {}


def _bounded(d: int, j: int) -> Bounded:
    if (d, j) not in _BOUNDED:
        _BOUNDED[d, j] = Bounded(d, j)
    return _BOUNDED[d, j]


def draw(spec: dict, d: int, S: int, rng: np.random.Generator, rep: int
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draws X (S, d) of q, real log-likelihoods L (S,) and surrogate values mu (S,)."""
    case = spec["case"]
    if case == "right":
        X = rng.standard_normal((S, d))
        L = -0.5 * np.sum(X**2, axis=1)
        kind = spec["kind"]
        h = (_smooth(d, rep % 50)(X) if kind == "smooth" else _bounded(d, rep % 50)(X)
             if kind == "bounded" else rng.standard_normal(S))
        return X, L, L + spec["eps"] * h
    sd = np.ones(d)
    if case in ("narrow", "t3"):
        sd[0] = spec["s"]
    X = sd * rng.standard_normal((S, d))
    mu = -0.5 * np.sum((X / sd) ** 2, axis=1)
    rest = -0.5 * np.sum(X[:, 1:] ** 2, axis=1)
    x1 = X[:, 0]
    if case == "narrow":
        L = rest - 0.5 * x1**2
    elif case == "lobe":
        w, a = spec["w"], spec["a"]
        L = rest + np.logaddexp(math.log1p(-w) - 0.5 * x1**2, math.log(w) - 0.5 * (x1 - a) ** 2)
    elif case == "t3":
        L = rest - 2.0 * np.log1p(x1**2 / 3.0)
    else:
        raise ValueError(case)
    return X, L, mu


def psis_tail_size(S: int) -> int:
    """PSIS's tail size M = ceil(min(S/5, 3 sqrt S)) (``pareto_k``'s before issue 17)."""
    return math.ceil(min(S / 5.0, 3.0 * math.sqrt(S)))


def k_longer_tail(lw: np.ndarray, frac: float, cap: float | None = 3.0) -> float:
    """k as ``pareto_k`` estimates it, from a tail of M = ceil(min(frac S, cap sqrt S))
    weights (ceil(frac S) if ``cap`` is None); judged from S >= 50 only (-inf below).
    frac = 0.2, cap = 3: PSIS's tail, ``pareto_k`` before issue 17."""
    from bayescalib.inference.importance import MIN_DRAWS, MIN_TAIL, _gpd_shape

    lw = np.sort(np.asarray(lw, float))
    S = lw.size
    if S < MIN_DRAWS:
        return -math.inf
    M = math.ceil(frac * S if cap is None else min(frac * S, cap * math.sqrt(S)))
    w = np.exp(lw - lw[-1])
    ex = w[S - M:] - w[S - M - 1]
    ex = ex[ex > 0]
    if ex.size < MIN_TAIL or ex[-1] <= ex[0] * (1 + 1e-12):
        return -math.inf
    n = ex.size
    return float((n * _gpd_shape(ex) + 10 * 0.5) / (n + 10))


#: rules: each maps c = {k (PSIS's tail), S, lsd, ws, k30 (importance_check's), k30u,
#: k305, k40} to "refused by the k test"
RULES: dict[str, object] = {
    "psis": lambda c: c["k"] >= K_REL,
    "psis-S": lambda c: c["k"] >= min(1.0 - 1.0 / math.log10(c["S"]), K_REL),
    "wmax 2": lambda c: c["ws"] >= 2.0 and c["k"] >= K_REL,
    "wmax 3": lambda c: c["ws"] >= 3.0 and c["k"] >= K_REL,
    "lsd 0.3": lambda c: c["lsd"] >= 0.3 and c["k"] >= K_REL,
    "lsd 0.5": lambda c: c["lsd"] >= 0.5 and c["k"] >= K_REL,
    "tail 20": lambda c: psis_tail_size(c["S"]) >= 20 and c["k"] >= K_REL,
    "tail 26": lambda c: psis_tail_size(c["S"]) >= 26 and c["k"] >= K_REL,
    "k 0.9": lambda c: c["k"] >= 0.9,
    "k 1.0": lambda c: c["k"] >= 1.0,
    "adopted": lambda c: c["k30"] >= K_REL,
    "M 0.4S<=3rtS": lambda c: c["k40"] >= K_REL,
    "M 0.3S": lambda c: c["k30u"] >= K_REL,
    "M 0.3S<=5rtS": lambda c: c["k305"] >= K_REL,
    "never": lambda c: False,
}


def run_cell(spec: dict, d: int, S: int, reps: int, seed: int = 0) -> dict:
    """Refusal rates (k alone, whole check) per rule and medians over ``reps`` replicates."""
    from bayescalib.inference.importance import importance_check

    ref_k = dict.fromkeys(RULES, 0)
    ref_all = dict.fromkeys(RULES, 0)
    lsds, esss, wss, ks = [], [], [], []
    for r in range(reps):
        rng = np.random.default_rng([seed, d, S, r, 17])
        X, L, mu = draw(spec, d, S, rng, r)
        res = importance_check(X, L, mu, sd_tol=SD_TOL)
        lw = L - mu
        W = np.exp(lw - lw.max())
        W /= W.sum()
        ws = float(S * W.max())
        k = res["pareto_k"]
        kk = -math.inf if k is None else float(k)
        ratio = np.asarray(res["sd_ratio"])
        others = (res["ess_fraction"] >= 0.5
                  and bool(np.all(np.abs(res["shift_sd"])
                                  <= 0.2 + 2 * np.asarray(res["shift_se"])))
                  and bool(np.all((ratio <= 1 + SD_TOL) & (ratio >= 1 / (1 + SD_TOL))))
                  and res["log_weight_sd"] <= 1.0)
        c = {"k": k_longer_tail(lw, 0.2), "S": S, "lsd": res["log_weight_sd"], "ws": ws,
             "k30": kk, "k40": k_longer_tail(lw, 0.4),
             "k30u": k_longer_tail(lw, 0.3, cap=None), "k305": k_longer_tail(lw, 0.3, cap=5.0)}
        for name, rule in RULES.items():
            bad = bool(rule(c))
            ref_k[name] += bad
            ref_all[name] += bad or not others
        lsds.append(res["log_weight_sd"])
        esss.append(res["ess_fraction"])
        wss.append(ws)
        ks.append(c["k"])
    return {"k": {n: v / reps for n, v in ref_k.items()},
            "all": {n: v / reps for n, v in ref_all.items()},
            "lsd": float(np.median(lsds)), "ess": float(np.median(esss)),
            "ws": float(np.median(wss)), "kmed": float(np.median(ks)),
            "k90": float(np.quantile(ks, 0.9))}


def tail_table(eps: float = 0.2, S: int = 64, reps: int = 1000) -> None:
    """1-D right cases with a smooth or bounded error: each of the 50 functions' pi
    (pi ∝ q exp(-eps h), q = N(0, 1), by quadrature) has a mass beyond 3 sd that is some
    multiple of q's; the k test's refusal rate at S draws (``reps`` replicates, reps / 50
    a function), grouped by that multiple."""
    x = np.linspace(-12.0, 12.0, 24_001)
    q = np.exp(-0.5 * x**2)
    q /= q.sum()
    far = np.abs(x) > 3.0
    print(f"\n1-D, error {eps:g} nats, {S} draws: the k test's refusals by how much more "
          f"mass than q pi has beyond 3 sd ({reps} replicates over 50 functions)\n")
    print("| error | pi / q mass beyond 3 sd | functions | k refusals: psis | adopted |")
    print("|---|---|---|---|---|")
    for kind, fun in (("smooth", _smooth), ("bounded", _bounded)):
        ratio = np.empty(50)
        for j in range(50):
            p = q * np.exp(-eps * fun(1, j)(x[:, None]))
            ratio[j] = (p[far].sum() / p.sum()) / q[far].sum()
        hits = np.zeros(50)
        hits30 = np.zeros(50)
        n = np.zeros(50)
        for r in range(reps):
            rng = np.random.default_rng([2, S, r])
            _X, L, mu = draw({"case": "right", "kind": kind, "eps": eps}, 1, S, rng, r)
            hits[r % 50] += k_longer_tail(L - mu, 0.2) >= K_REL
            hits30[r % 50] += k_longer_tail(L - mu, 0.3) >= K_REL
            n[r % 50] += 1
        for lo, hi in ((0.0, 1.5), (1.5, 3.0), (3.0, math.inf)):
            sel = (ratio >= lo) & (ratio < hi)
            if sel.any():
                rate = hits[sel].sum() / n[sel].sum()
                rate30 = hits30[sel].sum() / n[sel].sum()
                print(f"| {kind} | {lo:g}-{hi:g} | {int(sel.sum())} | {100 * rate:.0f} % | "
                      f"{100 * rate30:.0f} % |")


def _fmt_k(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{v:.2f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=500)
    ap.add_argument("--dims", default="1,7")
    ap.add_argument("--draws", default="50,64,128,256")
    ap.add_argument("--cases", default="", help="comma-separated label prefixes (default all)")
    a = ap.parse_args(argv)
    dims = [int(v) for v in a.dims.split(",")]
    draws = [int(v) for v in a.draws.split(",")]
    pref = [p.strip() for p in a.cases.split(",") if p.strip()]
    t0 = time.time()
    names = list(RULES)
    print(f"Refused, % of {a.reps} seeded replicates: by the k test alone / by the whole "
          f"check, per rule (sd_tol {SD_TOL:g}); log-w sd, ESS, S wmax, k: medians (k90: "
          "90th percentile; -: not estimated).\n")
    print("| case | d | S | log-w sd | ESS | S wmax | k | k90 | "
          + " | ".join(f"k: {n}" for n in names) + " | "
          + " | ".join(f"check: {n}" for n in names) + " |")
    print("|---|---|---|---|---|---|---|---|" + "---|" * (2 * len(names)))
    for label, spec in CASES:
        if pref and not any(label.startswith(p) for p in pref):
            continue
        for d in dims:
            for S in draws:
                c = run_cell(spec, d, S, a.reps)
                print(f"| {label} | {d} | {S} | {c['lsd']:.2f} | {100 * c['ess']:.0f} % | "
                      f"{c['ws']:.2f} | {_fmt_k(c['kmed'])} | {_fmt_k(c['k90'])} | "
                      + " | ".join(f"{100 * c['k'][n]:.0f}" for n in names) + " | "
                      + " | ".join(f"{100 * c['all'][n]:.0f}" for n in names) + " |",
                      flush=True)
    if not pref:
        tail_table()
    print(f"\n({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
