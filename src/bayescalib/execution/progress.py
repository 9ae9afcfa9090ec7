"""Progress of a run on the console: steps done and an estimate of the time left.

Snakemake reports "done of total steps"; the estimate added here is the pace so far,
``t_left = elapsed / done * (total - done)``, with ``elapsed`` counted from the first
report of the run. It assumes the remaining steps cost on average what the finished
ones did; steps differ (a solve, a discrepancy, a surrogate fit, the SMC), so the
estimate is a guide, not a promise, and it is said so. With active design the total
grows when a round adds solves: the estimate is for the steps scheduled so far.
"""

from __future__ import annotations

__all__ = ["format_duration", "progress_line"]


def format_duration(seconds: float) -> str:
    """A duration in words a person reads at a glance: '45 s', '3 min 20 s', '1 h 05 min'."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {(s % 3600) // 60:02d} min"


def progress_line(done: int, total: int, elapsed_s: float) -> str:
    """'12 of 84 steps (14 %) done, about 3 min 10 s left at the pace so far'.

    Parameters
    ----------
    done, total : steps finished and scheduled in this run.
    elapsed_s : wall time since the run's first step started, seconds.
    """
    pct = 100.0 * done / total if total else 100.0
    text = f"{done} of {total} steps ({pct:.0f} %) done"
    if 0 < done < total and elapsed_s > 0:
        left = elapsed_s / done * (total - done)
        text += f", about {format_duration(left)} left at the pace so far"
    elif done >= total and total:
        text += f" in {format_duration(elapsed_s)}"
    return text
