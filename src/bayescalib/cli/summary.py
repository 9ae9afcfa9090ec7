"""``bayescalib summary RESULTS_DIR``: a study's result as a table.

Reads ``summary.json`` of a finished study and prints the lines the run ended
with (posterior mean +- sd, solves used and failed; the verdict: the misfit when the
best fit is worse than the noise, converged or not and why, what to do), a table
per parameter (MAP, posterior mean, sd, equal-tailed credible intervals, ground
truth when known) and, for the active design, one row per round with its checks.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path


def add_parser(p: argparse.ArgumentParser) -> None:
    p.add_argument("results", help="the study's results folder (results/<study>) or its "
                                    "summary.json")


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def run(args: argparse.Namespace) -> int:
    from bayescalib.stages.errors import PipelineError
    from bayescalib.stages.files import read_json
    from bayescalib.stages.summary import run_line

    path = Path(args.results)
    if path.is_dir():
        path = path / "summary.json"
    if not path.is_file():
        raise ValueError(f"no summary.json at '{path}': run the study first "
                         "(snakemake --cores 2 --configfile config/<study>.yaml)")
    try:
        s = read_json(path)
    except PipelineError as exc:
        raise ValueError(str(exc)) from None
    from bayescalib.stages.verdict import verdict

    print(run_line(s))
    print(verdict(s))
    names = [p["name"] for p in s["parameters"]]
    units = {p["name"]: p.get("unit", "-") for p in s["parameters"]}
    cov = s["posterior_cov"]
    ci = s.get("credible_intervals") or {}
    levels = sorted(next(iter(ci.values()), {}).keys(), key=float)
    truth = s.get("ground_truth") or {}
    head = ["parameter", "unit", "MAP", "mean", "sd"] + \
        [f"{float(lv):.0%} equal-tailed" for lv in levels] + (["truth"] if truth else [])
    rows = [head]
    for k, n in enumerate(names):
        sd = (s.get("posterior_sd") or {}).get(n, math.sqrt(max(cov[k][k], 0.0)))
        row = [n, units[n], _fmt(s["map"].get(n)), _fmt(s["posterior_mean"].get(n)), _fmt(sd)]
        row += [f"[{_fmt(ci[n][lv][0])}, {_fmt(ci[n][lv][1])}]" for lv in levels]
        if truth:
            row.append(_fmt(truth.get(n)))
        rows.append(row)
    _table(rows)
    d = s.get("design") or {}
    if d.get("rounds"):
        print(f"\nactive design: {d['reason']}")
        rows = [["round", "solves", "failed", "GP error [nats]", "posterior change [sd]",
                 "settled", "posterior check"]]
        for r in d["rounds"]:
            pc = r["posterior_check_confirmed"]
            rows.append([str(r["round"]), str(r["n_solves"]), str(r["n_failed"]),
                         _fmt(r["gp_max_error_nats"]), _fmt(r["shift_sd"]),
                         "yes" if r["settled"] else "-",
                         "-" if pc is None else
                         ("confirmed" if pc else "NOT confirmed")
                         + ("" if r["log_weight_sd"] is None else
                            f" (log-weight sd {r['log_weight_sd']:.2g}, ESS "
                            f"{100 * r['ess_fraction']:.0f} %)")])
        _table(rows)
    elif d:
        print(f"\n{d.get('reason', '')}")
    failed = s.get("failed_runs") or []
    if failed:
        n_region = sum(bool(f.get("marks_infeasible")) for f in failed)
        print(f"\nfailed solves ({len(failed)}; {n_region} mark where the model cannot be "
              f"solved, and the posterior excludes their neighbourhood; the others failed "
              f"for the machine's sake and mark nothing):" if n_region else
              f"\nfailed solves ({len(failed)}):")
        rows = [["point", *names, "region", "reason"]]
        for f in failed:
            rows.append([str(f["point"]), *(_fmt(f["parameters"].get(n)) for n in names),
                         "yes" if f.get("marks_infeasible") else
                         "no" if "marks_infeasible" in f else "-",  # "-": written before
                         " ".join(str(f["reason"]).split())[:100]])
        _table(rows)
    return 0


def _table(rows: list[list[str]]) -> None:
    widths = [max(len(r[j]) for r in rows) for j in range(len(rows[0]))]
    for i, r in enumerate(rows):
        print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
        if i == 0:
            print("  ".join("-" * w for w in widths))
