"""NGSolve forward model: steady monolithic ALE fluid–biofilm interaction (paper App. B).

Modules: :mod:`~bayescalib.models.fsi.geometry` (flow cell, biofilm shapes, mesh, interface
chain), :mod:`~bayescalib.models.fsi.materials` (SVK, neo-Hooke), :mod:`~bayescalib.models.fsi.problem`
(problem description), :mod:`~bayescalib.models.fsi.solver` (the monolithic Newton/continuation
core), :mod:`~bayescalib.models.fsi.model` (config -> solve -> run record),
:mod:`~bayescalib.models.fsi.turek_hron` (validation benchmarks on the same core),
:mod:`~bayescalib.models.fsi.vtu` (field output). NGSolve is imported lazily, inside functions.
"""

from bayescalib.models.fsi.model import FSIModel

__all__ = ["FSIModel"]
