"""NGSolve forward model: steady monolithic ALE fluid–biofilm interaction (paper App. B).

Modules: :mod:`~bayescalib.fsi.geometry` (flow cell, biofilm shapes, mesh, interface
chain), :mod:`~bayescalib.fsi.materials` (SVK, neo-Hooke), :mod:`~bayescalib.fsi.problem`
(problem description), :mod:`~bayescalib.fsi.solver` (the monolithic Newton/continuation
core), :mod:`~bayescalib.fsi.model` (config -> solve -> run record),
:mod:`~bayescalib.fsi.turek_hron` (validation benchmarks on the same core),
:mod:`~bayescalib.fsi.vtu` (field output). NGSolve is imported lazily, inside functions.
"""

from bayescalib.fsi.model import FSIModel, solve_to_file

__all__ = ["FSIModel", "solve_to_file"]
