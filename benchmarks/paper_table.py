"""Compare finished paper studies with the numbers printed in the paper.

Reads ``results/<study>/summary.json`` of the studies under ``config/`` (run them
first, e.g. ``snakemake --cores 2 --configfile config/informed_prior.yaml``) and
prints, per study, a Markdown table: MAP and posterior mean from the paper
(Sec. 4.4 and 4.5 of ``bayescalib.tex``) beside this tool's MAP, posterior mean
+- sd and 90 % equal-tailed interval, the ground truth, and how the design ended
(solves, converged, the absolute fit check). The paper gives no sds or intervals.

    python benchmarks/paper_table.py [--results results]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

#: study name (summary.json "study") -> (section, paper's MAP, paper's posterior mean, n_train)
PAPER: dict[str, tuple[str, dict[str, float], dict[str, float], int]] = {
    "homogeneous_rkhs": ("4.4.1, uniform prior", {"E": 388.0, "nu": 0.266},
                         {"E": 431.0, "nu": -0.0071}, 1000),
    "informed_prior": ("4.4.1, informed prior", {"E": 361.0, "nu": 0.195},
                       {"E": 377.0, "nu": 0.08}, 1000),
    "uncertain_inflow": ("4.4.2, uncertain inflow", {"E": 322.0, "nu": 0.09},
                         {"E": 416.0, "nu": -0.09}, 1000),
    "heterogeneous": ("4.5, heterogeneous, uncertain inflow",
                      {"E1": 345.0, "nu1": 0.43, "E2": 135.0, "nu2": 0.30, "E3": 1034.0,
                       "nu3": -0.47},
                      {"E1": 443.0, "nu1": -0.15, "E2": 431.0, "nu2": -0.13, "E3": 637.0,
                       "nu3": -0.14}, 2000),
}
# the same study with the paper's fixed design (config/heterogeneous_fixed.yaml)
PAPER["heterogeneous_fixed"] = (PAPER["heterogeneous"][0] + ", fixed design",
                                *PAPER["heterogeneous"][1:])


def _f(v, nd: int = 4) -> str:
    return "-" if v is None else f"{float(v):.{nd}g}"


def study_table(s: dict) -> str:
    """Markdown table of one finished study beside the paper's numbers."""
    sec, p_map, p_pm, p_n = PAPER.get(s["study"], ("-", {}, {}, None))
    uncertain = {p["name"] for p in s["parameters"] if p.get("uncertain")}
    # with uncertain conditions the paper's MAP is that of the marginal posterior
    ours_map = (s.get("map_marginal") or s["map"]) if uncertain else s["map"]
    ci = s.get("credible_intervals") or {}
    truth = s.get("ground_truth") or {}
    rows = ["| parameter | unit | paper MAP | MAP | paper mean | mean +- sd | 90 % interval | truth |",
            "|---|---|---|---|---|---|---|---|"]
    for p in s["parameters"]:
        n = p["name"]
        lo_hi = (ci.get(n) or {}).get("0.9")
        rows.append(
            f"| {n}{' (uncertain)' if n in uncertain else ''} | {p.get('unit', '-')} "
            f"| {_f(p_map.get(n))} | {_f(ours_map.get(n))} | {_f(p_pm.get(n))} "
            f"| {_f(s['posterior_mean'][n])} +- {_f(s['posterior_sd'][n], 2)} "
            f"| {'-' if not lo_hi else f'[{_f(lo_hi[0])}, {_f(lo_hi[1])}]'} "
            f"| {_f(truth.get(n))} |")
    d = s.get("design") or {}
    fit = s.get("fit")
    state = {True: "converged", False: "NOT converged", None: "not checked (fixed design)"}[
        d.get("converged")]
    tail = (f"\nSection {sec}; paper: {p_n or '-'} solves (fixed Sobol design). This run: "
            f"{d.get('n_solves', s.get('n_train'))} solves ({d.get('strategy', 'fixed')} design, "
            f"{s.get('n_failed', 0)} failed), {state}, measure {s['measure']}.")
    check = s.get("posterior_check") or {}
    if d.get("converged") is None and check.get("words"):
        verdict = "confirmed" if check.get("confirmed") else "NOT confirmed"
        tail += (f" Its posterior, checked with real solves of {check.get('n_draws')} of its "
                 f"draws: {verdict} (log-weight sd {check.get('log_weight_sd', float('nan')):.2g}"
                 f" nats, ESS {100 * check.get('ess_fraction', float('nan')):.0f} %).")
    if fit:
        tail += f" Fit: {fit['words']}."
    return "\n".join(rows) + "\n" + tail


def measures_table(s: dict) -> str:
    """Per-measure results of a study with several measures (Sec. 4.2)."""
    names = [p["name"] for p in s["parameters"]]
    rows = ["| measure | " + " | ".join(f"MAP {n}" for n in names) + " | "
            + " | ".join(f"mean +- sd {n}" for n in names) + " | solves (failed) |",
            "|---|" + "---|" * (2 * len(names) + 1)]
    for m, r in s["measures"].items():
        rows.append(f"| {m} | " + " | ".join(_f(r["map"][n]) for n in names) + " | "
                    + " | ".join(f"{_f(r['posterior_mean'][n])} +- {_f(r['posterior_sd'][n], 2)}"
                                 for n in names)
                    + f" | {r['n_train']} ({r['n_failed']}) |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", default="results", help="results folder (default: results)")
    args = ap.parse_args(argv)
    found = 0
    for path in sorted(Path(args.results).glob("*/summary.json")):
        s = json.loads(path.read_text())
        found += 1
        print(f"## {s['study']}  ({path})\n")
        print(study_table(s) if len(s["measures"]) == 1 else measures_table(s))
        print()
    if not found:
        print(f"no summary.json under {args.results}/*/: run the studies first")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
