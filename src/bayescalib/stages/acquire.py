"""Stage ``acquire`` (rule ``acquire``): the end of an active round, as a JSON record.

The surrogate's trust check, the change of the posterior since the previous round, the
stop rule and, unless it stops, the next batch of design points to solve
(:func:`bayescalib.inference.rounds.decide`). The next round's solves are read from
this record.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from bayescalib.stages.errors import PipelineError
from bayescalib.stages.files import read_stage_file, write_json

__all__ = ["acquire"]

log = logging.getLogger("bayescalib")


def acquire(round_index: int, training_path: str | Path, surrogate_path: str | Path,
            particles_path: str | Path, previous_path: str | Path | None,
            active: Mapping[str, Any], check: Mapping[str, Any],
            parameters: Sequence[Mapping[str, Any]], out_path: str | Path) -> dict[str, Any]:
    """Active design, end of round ``round_index``: trust check, posterior change,
    posterior check of a check round, stop rule and the next batch
    (:func:`bayescalib.inference.rounds.decide`), as JSON. ``check`` is the
    ``posterior_check`` section (the rule's param keeps its name)."""
    from bayescalib.inference.parameters import ParameterSpace
    from bayescalib.inference.rounds import Evaluations, decide

    tab = read_stage_file(training_path, "training table")
    gp = read_stage_file(surrogate_path, "surrogate")
    res = read_stage_file(particles_path, "SMC particle file")
    previous = None if not previous_path else \
        read_stage_file(previous_path, "active round record")
    try:
        rec = decide(int(round_index), Evaluations.from_rows(tab), gp, res,
                     ParameterSpace.from_config(parameters), active, check, previous)
    except ValueError as exc:
        raise PipelineError(f"active round {round_index}: {exc}. Delete results/<study>/active "
                            "and the runs of the active rounds, then rerun.") from None
    write_json(out_path, rec)
    log.info("active round %d (%d solves): %s", round_index, rec["n_solves"], rec["reason"])
    return rec
