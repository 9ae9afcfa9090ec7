"""Paper-quality figures of the calibration results, from plain arrays.

Every public function takes NumPy arrays (no other bayescalib objects),
writes one figure to any number of paths (format from the suffix, ``dpi``
argument), returns the list of written paths and releases the figure (pass
``return_figure=True`` to get ``(paths, Figure)`` instead). Weighted particles
are accepted everywhere; weights are normalized to sum to one.

Modules (one figure family each)
--------------------------------
* :mod:`.response`    -- likelihood / log-likelihood / GP std over a 2-D design space
* :mod:`.convergence` -- GP error over the number of training points
* :mod:`.joint`       -- joint 2-D posterior with marginals and approximations
* :mod:`.particles`   -- SMC particles with weight as size and colour
* :mod:`.marginals`   -- 1-D marginals and corner (pair) plots
* :mod:`.parallel`    -- parallel-axis plot of particles coloured by density
* :mod:`.interfaces`  -- interface curves and scalar residuals along the interface
* :mod:`.fields`      -- velocity, pressure and displacement fields on the mesh
* :mod:`.segmentation` -- image observations with the interface traced from them

Helpers: :mod:`.style` (rc context, palette, labels), :mod:`.gaussian`
(probability ellipses); weighted KDE and HPD thresholds come from
:mod:`bayescalib.inference.weights`, the module the posterior summaries use.
"""

from .convergence import plot_gp_convergence
from .fields import plot_fields
from .gaussian import chi2_radius2, ellipse_axes, ellipse_points
from .interfaces import plot_interface_residual, plot_interfaces
from .joint import plot_joint_posterior
from .marginals import plot_marginals_1d, plot_pair_marginals
from .parallel import plot_parallel_axes
from .particles import plot_particles
from .response import plot_response_surface
from .segmentation import plot_segmentation
from .style import axis_label, paper_style

__all__ = [
    "axis_label",
    "chi2_radius2",
    "ellipse_axes",
    "ellipse_points",
    "paper_style",
    "plot_fields",
    "plot_gp_convergence",
    "plot_interface_residual",
    "plot_interfaces",
    "plot_joint_posterior",
    "plot_marginals_1d",
    "plot_pair_marginals",
    "plot_parallel_axes",
    "plot_particles",
    "plot_response_surface",
    "plot_segmentation",
]
