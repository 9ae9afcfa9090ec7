"""bayescalib: Bayesian calibration of coupled computational mechanics models
from observed interface shapes.

The package is the science of the pipeline as an importable library; the
Snakemake workflow in the repository calls it through thin scripts. Importing
the package is cheap: heavy dependencies (NGSolve, GPy, torch, vtk) are only
imported by the modules that need them.
"""

__version__ = "0.1.0"
