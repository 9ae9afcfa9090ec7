"""The log of a job: where the library's log records, Python's warnings and the error
that ends the job go (:func:`setup_logging`).

Every job sets it up before its stage runs: a job of the job server in
:func:`bayescalib.execution.jobserver.run_job`, a rule with a script in ``scripts/``
first thing.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

__all__ = ["setup_logging"]


def setup_logging(path: str | Path | None) -> None:
    """Send the library's log records to ``path`` (a rule's log file) and stderr.

    With a log file (a job of the workflow), the console gets warnings and errors only:
    a study runs thousands of jobs, and their information is in their logs. Python's
    warnings (the libraries': GPy's and NumPy's RuntimeWarnings, Matplotlib's, with
    their site-packages paths) go to the log file only, not to the console.
    """
    root = logging.getLogger("bayescalib")
    root.setLevel(logging.INFO)
    fmt = logging.Formatter("%(asctime)s %(levelname)s %(message)s")
    console = logging.StreamHandler()
    if path is not None:
        console.setLevel(logging.WARNING)
    handlers: list[logging.Handler] = [console]
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        handlers.append(logging.FileHandler(path, mode="w"))
    for h in handlers:
        h.setFormatter(fmt)
        root.addHandler(h)
    if path is not None:
        logging.captureWarnings(True)
        warned = logging.getLogger("py.warnings")
        warned.propagate = False  # not to the console (the root logger's last resort)
        for h in [h for h in warned.handlers if getattr(h, "_bayescalib_log", False)]:
            warned.removeHandler(h)  # an earlier job's log in this process
        warned.addHandler(handlers[-1])
        handlers[-1]._bayescalib_log = True  # type: ignore[attr-defined]
        # a job of a study (its log under <root>/logs/) marks itself running, so that a
        # new run of the study waits for the orphans of a killed one
        parts = Path(path).resolve().parts
        if "logs" in parts:
            from bayescalib.study import hold_job_lock

            hold_job_lock(Path(*parts[: len(parts) - 1 - parts[::-1].index("logs")]))
        # an error that ends the job goes into the rule's log too, not only to the console
        previous = sys.excepthook

        file_handler = handlers[-1]

        def _log_and_raise(kind, exc, tb):
            if not issubclass(kind, KeyboardInterrupt):
                file_handler.handle(root.makeRecord(
                    root.name, logging.ERROR, __file__, 0, "%s: %s", (kind.__name__, exc),
                    (kind, exc, tb)))
                file_handler.flush()
            previous(kind, exc, tb)

        sys.excepthook = _log_and_raise
