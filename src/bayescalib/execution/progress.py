"""What the console says while a study runs: a few lines per round, not one per step.

Snakemake's own progress is "done of total steps", one line per finished step (192 for
the default study), and with an active design its total grows as the rounds add solves,
so its percentage goes backwards (85 % -> 63 %). The console of a run says instead
(:class:`RunConsole`, fed with Snakemake's job events by the logger plugin the default
profile names, ``src/snakemake_logger_plugin_bayescalib``):

* one line at the start: the study, its design and the budget of solves
  (``design.active.max_solves``), and where a resumed run starts from;
* per active round, when its record is written (the ``acquire`` job): the solves done of
  the budget, what the stop rule decided and why in a few words, and the round's
  posterior (:func:`round_lines`, from the structured fields of the round record);
* with a fixed design, one line when its solves are done;
* while a stage runs long, at most one line a minute (``interval_s``): what runs and the
  solves done of the budget.

The run's end (the Snakefile's ``onsuccess``) adds the posterior and the verdict
(:func:`bayescalib.stages.verdict.verdict`). Everything here is pure but for reading the
round records and listing the run records at the start (:func:`run_plan`).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["RunConsole", "format_duration", "get_plan", "round_lines", "run_plan",
           "set_plan"]

#: the plan of the run this process was started for (set by the Snakefile when it is
#: parsed, read by the logger plugin in the same process); None outside a run
_PLAN: dict[str, Any] | None = None


def set_plan(plan: Mapping[str, Any] | None) -> None:
    """Hand the run's plan (:func:`run_plan`) to the console of this process."""
    global _PLAN
    _PLAN = None if plan is None else dict(plan)


def get_plan() -> dict[str, Any] | None:
    return _PLAN


def format_duration(seconds: float) -> str:
    """A duration in words a person reads at a glance: '45 s', '3 min 20 s', '1 h 05 min'."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {(s % 3600) // 60:02d} min"


def _read_json(path: str | Path) -> Any:
    return json.loads(Path(path).read_text())


def run_plan(name: str, root: str | Path, *, active: bool, budget: int,
             units: Mapping[str, str]) -> dict[str, Any]:
    """What the console needs to know of a study before its first step.

    ``budget``: design.active.max_solves (active design) or the number of design points
    (fixed); ``units``: parameter name -> unit. Lists ``root/runs`` (the solves already
    done) and, for an active design, reads the last round record already written, so
    that a resumed run says where it starts from.
    """
    root = Path(root)
    runs = root / "runs"
    n_solved = sum(1 for p in runs.glob("*.h5") if p.stem.isdigit()) if runs.is_dir() else 0
    last = None
    if active:
        r = 0
        while (root / "active" / str(r) / "acquire.json").is_file():
            r += 1
        if r:
            try:
                rec = _read_json(root / "active" / str(r - 1) / "acquire.json")
                last = {"round": int(rec["round"]), "n_solves": int(rec["n_solves"]),
                        "stop": bool(rec.get("stop"))}
            except (OSError, ValueError, KeyError, TypeError):
                last = None  # unreadable: the run itself sets it aside and says so
    return {"study": name, "root": str(root), "active": bool(active), "budget": int(budget),
            "units": dict(units), "n_solved": int(n_solved), "last_round": last}


def header_line(plan: Mapping[str, Any]) -> str:
    """The first line of a run: study, design, budget, and where a resumed run starts."""
    logs = f"{plan['root']}/logs/"
    if plan["active"]:
        head = (f"bayescalib {plan['study']}: active design, at most {plan['budget']} solves "
                f"(design.active.max_solves)")
        last = plan.get("last_round")
        if last and last["stop"]:
            head += f"; its rounds ended before (round {last['round']}, {last['n_solves']} solves)"
        elif last:
            head += (f"; resuming after round {last['round']} ({last['n_solves']} solves "
                     f"done)")
        elif plan.get("n_solved"):
            head += f"; resuming with {plan['n_solved']} solves done"
    else:
        head = f"bayescalib {plan['study']}: fixed design of {plan['budget']} solves"
        if plan.get("n_solved"):
            head += f" ({min(plan['n_solved'], plan['budget'])} done before)"
    return f"{head}. Each step's log: {logs}"


def _sig(v: float, n: int = 3) -> str:
    """``v`` to ``n`` significant digits, without an exponent where a person reads the
    plain number more easily (122 -> '120' at 2 digits, not '1.2e+02')."""
    v = float(f"{float(v):.{n}g}")  # rounded first: 9.97 at 2 digits is 10, not 10.0
    if v == 0 or not math.isfinite(v):
        return f"{v:g}"
    mag = math.floor(math.log10(abs(v)))
    if not -3 <= mag < 6:
        return f"{v:.{n}g}"
    return f"{v:.{max(n - 1 - mag, 0)}f}"


def _g(v: float) -> str:
    return _sig(v, 3)


def _posterior_text(rec: Mapping[str, Any], units: Mapping[str, str], most: int = 4) -> str:
    names = rec.get("names") or []
    mean, sd = rec["posterior"]["mean"], rec["posterior"]["sd"]
    cut = {c["name"]: c["side"] for c in rec.get("against_bounds") or []}
    parts = []
    for k, n in enumerate(names[:most]):
        u = units.get(n, "-")
        parts.append(f"{n} = {_g(mean[k])} +- {_sig(sd[k], 2)}"
                     + ("" if u in ("-", "", None) else f" {u}")
                     + (f" (cut by its prior's {cut[n]} end)" if n in cut else ""))
    more = f" (and {len(names) - most} more)" if len(names) > most else ""
    return ", ".join(parts) + more


def _decision(rec: Mapping[str, Any]) -> str:
    """What round ``rec``'s stop rule decided, in a few words, from its fields."""
    pc = rec.get("posterior_check")
    change = rec.get("change") or {}
    if rec.get("converged"):
        if pc is not None:
            k = int(pc["n_draws"]) - int(pc.get("n_failed") or 0)
            return (f"converged: {k} real solves of its draws confirm round {pc['round']}'s "
                    f"posterior")
        return "converged on the surrogate's own checks (no posterior check)"
    if rec.get("stop"):
        return "stopped, NOT converged (the verdict at the end says why)"
    nxt = rec.get("next") or {}
    kinds = list(nxt.get("kind") or [])
    q = len(nxt.get("points") or [])
    if pc is not None and pc.get("decision") == "superseded":
        said = (f"the posterior moved away from round {pc['round']}'s while its draws were "
                f"solved, so that check was stopped")
    elif pc is not None and not pc["confirmed"]:
        said = f"its draws did not confirm round {pc['round']}'s posterior"
    elif pc is not None:
        said = f"round {pc['round']}'s posterior was confirmed but moved when its draws were added"
    elif rec.get("round") == 0 or not change:
        said = "the first posterior"
    elif not rec.get("settled"):
        said = f"the posterior moved {_sig(change['shift_sd'], 2)} sd"
    else:
        said = f"the posterior settled ({rec.get('settled_streak', 0)} round(s) in a row)"
    if kinds and all(k == "posterior_check" for k in kinds):
        return f"{said}; {q} draws of it are solved next as its check"
    return f"{said}; {q} more solves next"


def round_lines(rec: Mapping[str, Any], budget: int | None, units: Mapping[str, str],
                elapsed_s: float | None = None) -> list[str]:
    """The console's lines for a finished active round (its acquire.json record): the
    solves done of the budget and the stop rule's decision, then the round's posterior."""
    when = "" if elapsed_s is None else f" [{format_duration(elapsed_s)}]"
    of = f" of {budget}" if budget is not None else ""
    failed = int(rec.get("n_failed") or 0)
    lines = [f"round {rec['round']}{when}: {rec['n_solves']}{of} solves"
             + (f" ({failed} failed)" if failed else "") + f"; {_decision(rec)}",
             f"  posterior: {_posterior_text(rec, units)}"]
    if rec.get("stop"):
        lines.append("  final posterior, figures and summary next")
    return lines


#: what a rule is doing, for the lines of a long stage
_PHASES = {
    "solve": "solves", "discrepancy": "discrepancies", "ground_truth": "the ground truth",
    "base_state": "the base state", "observe": "the observations",
    "gather_round": "the training table", "gather": "the training table",
    "train_round": "the surrogate", "train_surrogate": "the surrogate",
    "smc_round": "SMC", "smc": "SMC", "acquire": "the next solves",
    "marginalize": "the posterior's summaries", "predictive_solve": "solves of posterior draws",
    "posterior_check": "the posterior check", "posterior_mean_solve": "the posterior mean",
    "convergence": "the GP convergence study", "summary": "summary.json",
}


def _phase(rule: str) -> str:
    if rule.startswith("fig_"):
        return "figures"
    if rule.startswith("diagnos"):
        return "the diagnosis"
    return _PHASES.get(rule, rule)


class RunConsole:
    """The console of one run, fed with Snakemake's job events (the module docstring).

    Each method returns the lines to print (often none). ``read_record`` reads a round
    record (JSON) and ``clock`` gives seconds; both are arguments so that it can be
    tested without a run.
    """

    def __init__(self, plan: Mapping[str, Any], *, interval_s: float = 60.0,
                 read_record: Callable[[str], Any] = _read_json,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.plan = dict(plan)
        self.interval_s = float(interval_s)
        self._read = read_record
        self._clock = clock
        self._t0 = clock()
        self._last_line = self._t0
        self._jobs: dict[int, tuple[str, dict, list]] = {}
        self.solves = int(plan.get("n_solved") or 0)
        self._started = False
        self._design_done = False

    def _elapsed(self) -> float:
        return self._clock() - self._t0

    def _said(self, lines: list[str]) -> list[str]:
        if lines:
            self._last_line = self._clock()
        return lines

    def start(self) -> list[str]:
        """The header, once."""
        if self._started:
            return []
        self._started = True
        return self._said([header_line(self.plan)])

    def _heartbeat(self) -> list[str]:
        if self._clock() - self._last_line < self.interval_s or not self._jobs:
            return []
        running: list[str] = []
        for rule, _, _ in self._jobs.values():
            p = _phase(rule)
            if p not in running:
                running.append(p)
        return self._said([(f"  [{format_duration(self._elapsed())}] running: "
                            f"{', '.join(running)}; {self.solves} of {self.plan['budget']} "
                            f"solves done")])

    def job_info(self, jobid: int, rule: str, wildcards: Mapping[str, Any] | None,
                 output: Sequence[str] | None) -> list[str]:
        """A job starts."""
        out = self.start()
        self._jobs[int(jobid)] = (str(rule), dict(wildcards or {}), list(output or []))
        return out + self._heartbeat()

    def job_finished(self, jobid: int) -> list[str]:
        """A job ended well."""
        job = self._jobs.pop(int(jobid), None)
        if job is None:
            return []
        rule, _, output = job
        out: list[str] = []
        if rule == "solve":
            self.solves += 1
            if not self.plan["active"] and not self._design_done \
                    and self.solves >= self.plan["budget"]:
                self._design_done = True
                out += [(f"all {self.plan['budget']} solves done "
                         f"[{format_duration(self._elapsed())}]; surrogate, posterior, "
                         "figures and summary next")]
        elif rule == "acquire" and output:
            try:
                rec = self._read(output[0])
                lines = round_lines(rec, self.plan["budget"], self.plan.get("units") or {},
                                    self._elapsed())
            except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
                return self._said([f"round record {output[0]} unreadable: {exc!r}"])
            self.solves = int(rec["n_solves"])
            out += lines
        return self._said(out) or self._heartbeat()
