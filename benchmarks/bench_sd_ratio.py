"""The sd ratio of the posterior check (bayescalib.inference.importance) and its Monte
Carlo error: false refusals of a right posterior, detection of a wrong one.

The real posterior is pi = N(0, I_d) (coordinates in units of pi's sd); S draws of a
surrogate posterior q are solved and checked. Cases:

* ``right``: q = pi; the surrogate's log-likelihood mu carries an error eps * h(x), so
  the log-weights are log w = -eps * h(x), scaled to a spread of eps nats. Two kinds of
  h: ``noise`` (independent per draw: pi and q agree exactly, only the weights scatter)
  and ``smooth`` (a random smooth function, 50 random Fourier features of length scale
  1 (pi's sd), with its constant, linear and quadratic Hermite components under q taken
  out: pi ∝ q exp(-eps h) then has q's means and covariances to first order in eps; the
  second-order differences, from 200 000 draws, are printed with the table);
  the check should confirm, and its refusals are false. ``right (t5 marginals)``: the
  same with the noise error, but pi = q has independent Student-t marginals (5 degrees
  of freedom, unit sd; not Gaussian: heavier tails make a sample sd noisier);
* ``narrow`` / ``wide``: q = N(0, diag(s^2)) with s < 1 (too narrow) or s > 1 (too
  wide) in the first direction only (``1 dir``) or in all; the weights are exact;
  the check should refuse.

For each cell (case, d, S; ``--reps`` seeded replicates) the rates of "not confirmed"
are printed for the sd criterion alone and for the whole check, under the rules:

* ``now``: every sd ratio within a factor 1 + sd_tol (sd_tol = 0.2);
* ``delta``: |log ratio| <= log(1 + sd_tol) + z se, se the delta-method (influence-
  function) standard error of the log sd ratio on the same draws, z = 2;
* ``null``: the same with the se of the log ratio if the weights were unrelated to x,
  0.5 sqrt(kappa (1/ESS - 1/S)), kappa the draws' variance of (x - m)^2 / sd^2
  (2 for a Gaussian);
* ``wide-only``: the ``delta`` allowance only where the ratio is below 1 (q too wide);
  a ratio above 1 (pi wider than q: q too narrow) keeps the bare factor;
* ``max``: |log ratio| <= max(log(1 + sd_tol), z se) with the delta-method se: a ratio
  is refused only where it is both beyond the factor and beyond its own noise.

Besides the rates, the table gives the 95th percentile over replicates of the largest
sd ratio's factor, max over parameters of max(ratio, 1 / ratio) (``q95 factor``).

Last, the refusal seen on the 7-D FSI study (32 draws, log-weight sd 0.41 nats, ESS 83 %,
largest of 7 sd ratios 1.27) against these models: how often the largest sd factor
reaches 1.27 under a right posterior and under ones too narrow by 0.9, 0.8, 0.7 in one
direction (a noise error on top brings the log-weight sd to 0.41 nats).

Run::

    python benchmarks/bench_sd_ratio.py [--reps 500] [--dims 1,2,7] [--draws 16,32,64]
        [--fsi-reps 2000]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

SD_TOL = 0.2
Z = 2.0
RULES = ("now", "delta", "null", "wide-only", "max")


def log_sd_ratio_se(X: np.ndarray, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The delta-method and the weights-only standard errors of the log sd ratio.

    X (S, d) draws of q, W (S,) normalized importance weights. The log sd ratio is
    (log v_is - log v_q) / 2 with v_is = sum W (x - m_is)^2 and v_q the draws' variance;
    its influence function at draw s is (S W_s z_is,s - z_q,s) / 2 with
    z_is = (x - m_is)^2 / v_is - 1 and z_q = (x - m_q)^2 / v_q - 1, and the se is the
    root of the sum of its squares over S^2. The weights-only se treats the z as
    independent of the weights: 0.5 sqrt(kappa (1/ESS - 1/S)).
    """
    S = X.shape[0]
    m_is = W @ X
    v_is = W @ (X - m_is) ** 2
    m_q = X.mean(axis=0)
    v_q = X.var(axis=0)
    z_is = (X - m_is) ** 2 / np.where(v_is > 0, v_is, 1.0) - 1.0
    z_q = (X - m_q) ** 2 / np.where(v_q > 0, v_q, 1.0) - 1.0
    psi = S * W[:, None] * z_is - z_q
    delta = 0.5 * np.sqrt(np.sum(psi**2, axis=0)) / S
    kappa = z_q.var(axis=0)
    null = 0.5 * np.sqrt(kappa * max(float(np.sum(W**2)) - 1.0 / S, 0.0))
    return delta, null


def sd_ok(rule: str, ratio: np.ndarray, se_delta: np.ndarray | None = None,
          se_null: np.ndarray | None = None) -> bool:
    """The sd criterion under ``rule`` (module docstring): True where it passes."""
    lr = np.log(np.maximum(ratio, 1e-300))
    t = math.log1p(SD_TOL)
    if rule == "now":
        return bool(np.all(np.abs(lr) <= t))
    if rule == "delta":
        return bool(np.all(np.abs(lr) <= t + Z * se_delta))
    if rule == "null":
        return bool(np.all(np.abs(lr) <= t + Z * se_null))
    if rule == "wide-only":
        return bool(np.all((lr <= t) & (lr >= -t - Z * se_delta)))
    if rule == "max":
        return bool(np.all(np.abs(lr) <= np.maximum(t, Z * se_delta)))
    raise ValueError(rule)


class Smooth:
    """A random smooth function on R^d with no Hermite component of degree <= 2 under
    N(0, I): 50 random Fourier features (length scale 1) minus their constant, linear and
    quadratic parts (E h, E grad h, E Hessian h: Gaussian integration by parts), scaled
    to unit sd under N(0, I)."""

    def __init__(self, d: int, rng: np.random.Generator, J: int = 50) -> None:
        self.om = rng.standard_normal((J, d))
        self.b = rng.uniform(0, 2 * np.pi, J)
        damp = np.exp(-0.5 * np.sum(self.om**2, axis=1))
        c = math.sqrt(2.0 / J)
        self.a0 = c * np.sum(damp * np.cos(self.b))
        self.a1 = -c * (damp * np.sin(self.b)) @ self.om
        self.A = -c * np.einsum("j,ji,jk->ik", damp * np.cos(self.b), self.om, self.om)
        self.scale = 1.0
        self.scale = float(np.std(self(rng.standard_normal((50_000, d)))))

    def __call__(self, X: np.ndarray) -> np.ndarray:
        c = math.sqrt(2.0 / self.b.size)
        h = c * np.cos(X @ self.om.T + self.b).sum(axis=1)
        quad = 0.5 * (np.einsum("si,ik,sk->s", X, self.A, X) - np.trace(self.A))
        return (h - self.a0 - X @ self.a1 - quad) / self.scale


def draw_case(case: str, d: int, S: int, rng: np.random.Generator, eps: float,
              s: float, all_dirs: bool, h: Smooth | None, tails: bool = False):
    """Draws X (S, d) of q, real log-likelihoods L and surrogate values mu."""
    if case == "right":
        if tails:  # Student t with 5 degrees of freedom, unit sd
            X = rng.standard_t(5, (S, d)) * math.sqrt(3.0 / 5.0)
            L = -3.0 * np.sum(np.log1p(X**2 / 3.0), axis=1)
        else:
            X = rng.standard_normal((S, d))
            L = -0.5 * np.sum(X**2, axis=1)
        err = rng.standard_normal(S) if h is None else h(X)
        return X, L, L + eps * err
    sd = np.ones(d)
    if all_dirs:
        sd[:] = s
    else:
        sd[0] = s
    X = sd * rng.standard_normal((S, d))
    mu = -0.5 * np.sum((X / sd) ** 2, axis=1)
    if eps > 0:  # a noise error on top (independent of x: the target stays pi)
        mu = mu + eps * rng.standard_normal(S)
    return X, -0.5 * np.sum(X**2, axis=1), mu


def truth_of_smooth(h: Smooth, d: int, eps: float, rng: np.random.Generator) -> tuple[float, float]:
    """pi's largest |mean shift| (q's sd) and largest |log sd ratio| for q = N(0, I),
    pi ∝ q exp(-eps h), from 200 000 draws."""
    X = rng.standard_normal((200_000, d))
    lw = -eps * h(X)
    W = np.exp(lw - lw.max())
    W /= W.sum()
    m = W @ X
    v = W @ (X - m) ** 2
    return float(np.max(np.abs(m))), float(np.max(np.abs(0.5 * np.log(v))))


N_SMOOTH = 50
_SMOOTH: dict[tuple[int, int], Smooth] = {}


def _smooth(d: int, j: int) -> Smooth:
    """The j-th of ``N_SMOOTH`` seeded smooth error functions in d dimensions."""
    if (d, j) not in _SMOOTH:
        _SMOOTH[d, j] = Smooth(d, np.random.default_rng([0, d, j, 7]))
    return _SMOOTH[d, j]


def run_cell(case: str, d: int, S: int, reps: int, eps: float = 0.0, s: float = 1.0,
             all_dirs: bool = False, kind: str = "noise", tails: bool = False,
             seed: int = 0) -> dict:
    from bayescalib.inference.importance import K_RELIABLE, importance_check

    refuse_sd = dict.fromkeys(RULES, 0)
    refuse_all = dict.fromkeys(RULES, 0)
    lsd, ess, fac = [], [], []
    for r in range(reps):
        rng = np.random.default_rng([seed, d, S, r])
        h = _smooth(d, r % N_SMOOTH) if kind == "smooth" else None
        X, L, mu = draw_case(case, d, S, rng, eps, s, all_dirs, h, tails)
        res = importance_check(X, L, mu, sd_tol=SD_TOL)
        lw = L - mu
        W = np.exp(lw - lw.max())
        W /= W.sum()
        se_d, se_n = log_sd_ratio_se(X, W)
        ratio = np.asarray(res["sd_ratio"])
        k = res["pareto_k"]
        others = ((k is None or k < K_RELIABLE) and res["ess_fraction"] >= 0.5
                  and bool(np.all(np.abs(res["shift_sd"])
                                  <= 0.2 + 2 * np.asarray(res["shift_se"])))
                  and res["log_weight_sd"] <= 1.0)
        for rule in RULES:
            ok = sd_ok(rule, ratio, se_d, se_n)
            refuse_sd[rule] += not ok
            refuse_all[rule] += not (ok and others)
        lsd.append(res["log_weight_sd"])
        fac.append(float(np.max(np.maximum(ratio, 1.0 / ratio))))
        ess.append(res["ess_fraction"])
    return {"sd": {k: v / reps for k, v in refuse_sd.items()},
            "all": {k: v / reps for k, v in refuse_all.items()},
            "lsd": float(np.median(lsd)), "ess": float(np.median(ess)),
            "q95": float(np.quantile(fac, 0.95))}


def fsi_case(reps: int, factor: float = 1.27, lsd: float = 0.41) -> None:
    """How likely the refusal seen on the 7-D FSI study (32 draws, log-weight sd 0.41
    nats, largest sd ratio 1.27) is under a right posterior and under mildly narrow ones:
    P(largest factor max(ratio, 1/ratio) >= ``factor``) at d = 7, S = 32, each case's
    log-weight sd brought to about ``lsd`` by a noise error."""
    from bayescalib.inference.importance import importance_check

    print(f"\nThe FSI refusal (d 7, 32 draws, log-weight sd about {lsd:g} nats): share of "
          f"{reps} replicates whose largest sd factor is >= {factor:g}\n")
    print("| case | log-w sd | ESS | P(largest factor >= " + f"{factor:g}) | P(sd refused now) |")
    print("|---|---|---|---|---|")
    cases = [("right, noise error", {"case": "right"}),
             ("right, smooth error", {"case": "right", "kind": "smooth"}),
             ("right (t5 marginals), noise error", {"case": "right", "tails": True})]
    for s in (0.9, 0.8, 0.7):
        cases.append((f"narrow {s:g}, 1 dir, + noise error", {"case": "narrow", "s": s}))
    for label, kw in cases:
        own = (1.0 - kw["s"] ** 2) / math.sqrt(2.0) if "s" in kw else 0.0
        eps = math.sqrt(max(lsd**2 - own**2, 0.0))
        hits, refused, lsds, ess = 0, 0, [], []
        for r in range(reps):
            rng = np.random.default_rng([1, r])
            h = _smooth(7, r % N_SMOOTH) if kw.get("kind") == "smooth" else None
            X, L, mu = draw_case(kw["case"], 7, 32, rng, eps, kw.get("s", 1.0), False, h,
                                 kw.get("tails", False))
            res = importance_check(X, L, mu, sd_tol=SD_TOL)
            ratio = np.asarray(res["sd_ratio"])
            hits += float(np.max(np.maximum(ratio, 1.0 / ratio))) >= factor
            refused += not sd_ok("now", ratio)
            lsds.append(res["log_weight_sd"])
            ess.append(res["ess_fraction"])
        print(f"| {label} | {np.median(lsds):.2f} | {100 * np.median(ess):.0f} % | "
              f"{100 * hits / reps:.1f} % | {100 * refused / reps:.0f} % |", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=500)
    ap.add_argument("--dims", default="1,2,7")
    ap.add_argument("--draws", default="16,32,64")
    ap.add_argument("--fsi-reps", type=int, default=2000,
                    help="replicates of the FSI-refusal table (0: leave it out)")
    a = ap.parse_args(argv)
    dims = [int(v) for v in a.dims.split(",")]
    draws = [int(v) for v in a.draws.split(",")]
    cases = ([(f"right, {kind} error {eps:g} nats", {"case": "right", "eps": eps, "kind": kind})
              for kind in ("noise", "smooth") for eps in (0.2, 0.4, 0.6)]
             + [(f"right (t5 marginals), noise error {eps:g} nats",
                 {"case": "right", "eps": eps, "tails": True}) for eps in (0.2, 0.4, 0.6)]
             + [(f"narrow {s:g}, {'all' if alld else '1 dir'}",
                 {"case": "narrow", "s": s, "all_dirs": alld})
                for s in (0.5, 0.7) for alld in (False, True)]
             + [(f"wide 1.5, {'all' if alld else '1 dir'}",
                 {"case": "wide", "s": 1.5, "all_dirs": alld}) for alld in (False, True)])
    t0 = time.time()
    print(f"Not confirmed, % of {a.reps} seeded replicates; sd criterion alone / whole "
          f"check; rules {', '.join(RULES)} (sd_tol {SD_TOL:g}, z {Z:g}); log-w sd and "
          "ESS: medians.\n")
    print("| case | d | S | log-w sd | ESS | q95 factor | " + " | ".join(f"sd: {r}" for r in RULES)
          + " | " + " | ".join(f"check: {r}" for r in RULES) + " |")
    print("|---|---|---|---|---|---|" + "---|" * (2 * len(RULES)))
    for label, kw in cases:
        for d in dims:
            for S in draws:
                c = run_cell(d=d, S=S, reps=a.reps, **kw)
                print(f"| {label} | {d} | {S} | {c['lsd']:.2f} | {100 * c['ess']:.0f} % | {c['q95']:.2f} | "
                      + " | ".join(f"{100 * c['sd'][r]:.0f}" for r in RULES) + " | "
                      + " | ".join(f"{100 * c['all'][r]:.0f}" for r in RULES) + " |",
                      flush=True)
    print("\nThe smooth error's own effect (q = N(0, I), pi ∝ q exp(-eps h), 200 000 draws; "
          "median over 20 functions): pi's largest |mean shift| (q sd) and largest "
          "|log sd ratio|:\n")
    print("| d | eps (nats) | largest shift | largest exp(abs log sd ratio) |")
    print("|---|---|---|---|")
    for d in dims:
        for eps in (0.2, 0.4, 0.6):
            tr = [truth_of_smooth(_smooth(d, r), d, eps,
                                  np.random.default_rng(r)) for r in range(20)]
            sh, lr = np.median(np.asarray(tr), axis=0)
            print(f"| {d} | {eps:g} | {sh:.3f} | {math.exp(lr):.3f} |")
    if a.fsi_reps:
        fsi_case(a.fsi_reps)
    print(f"\n({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
