"""The error of a stage that cannot proceed.

A stage raises :class:`PipelineError` when its inputs or settings do not allow its job
(too few successful solves, a file of another setup, observations in other units): the
message names what is wrong and what to change or run, and the job fails with it.
"""

from __future__ import annotations

__all__ = ["PipelineError"]


class PipelineError(RuntimeError):
    """A stage cannot proceed; the message says what to change."""
