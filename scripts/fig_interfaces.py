"""Rule `fig_interfaces`: undeformed, observed and posterior-sample interfaces."""
from bayescalib.stages import setup_logging
from bayescalib.stages.figures import interface_figure

setup_logging(snakemake.log[0])  # noqa: F821
interface_figure(
    snakemake.input.obs,  # noqa: F821
    snakemake.input.samples,  # noqa: F821
    snakemake.params.plots,  # noqa: F821
    snakemake.params.stem,  # noqa: F821
    ground_truth_run=snakemake.input.get("truth"),  # noqa: F821
)
