"""The diagnosis's solve context: the settings every step of the diagnosis needs, built
once from the validated config (:meth:`DiagnosisContext.build`) at the top of
:func:`bayescalib.diagnosis.stage.run_diagnosis`, so that its steps take the context and
their own inputs instead of the same dozen settings again and again.

It carries the forward model and the parameters (how a point is solved), the observed
interfaces as the diagnosis uses them (thinned to one node per noise correlation
length) with the resolved noise settings of the predictive check, the validated
``diagnose`` section, the work folder, workers and warm start, and the settings of the
extended calibrations (:meth:`DiagnosisContext.chain`: the arguments that
:func:`bayescalib.stages.chain.calibrate_rounds` hands to its
:class:`~bayescalib.stages.chain.SolvePath` and rounds). The diagnosis's own solves
(posterior draws, the linearization, signatures, the registration's fit) go through
:meth:`DiagnosisContext.solve` and its predictive checks through
:meth:`DiagnosisContext.predictive_check`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["IMAGE_NOISE_LAG_PIXELS", "MAX_SURFACE_NODES", "SURFACE_SPACING_SHARE",
           "DiagnosisContext", "diagnosis_nodes", "noise_lag", "resolve_noise_model",
           "rim_height", "surface_nodes", "thinned_observations"]

#: lag of the noise estimate for interfaces traced from images, in pixel sizes (see
#: :func:`bayescalib.diagnosis.residuals.estimate_noise`)
IMAGE_NOISE_LAG_PIXELS = 5.0


def _image_pixel_sizes(observations: Mapping[str, Any]) -> list[float]:
    """Pixel sizes (mm) of the image files among the observations (none: not images);
    of an OCT volume (``pixel_size: [dx, dy, dz]``, a folder of B-scans or a stack) its
    largest voxel edge."""
    from bayescalib.io.observations import IMAGE_SUFFIXES, UNITS, VOLUME_SUFFIXES

    if observations.get("source") != "files":
        return []
    out = []
    for e in observations.get("files") or []:
        size, path = e.get("pixel_size"), Path(e["path"])
        if not size:
            continue
        if isinstance(size, list | tuple):  # a volume's voxel
            out.append(max(float(v) for v in size) * UNITS[e.get("units") or "mm"])
        elif path.suffix.lower() in IMAGE_SUFFIXES | VOLUME_SUFFIXES or path.is_dir():
            out.append(float(size) * UNITS[e.get("units") or "mm"])
    return out


def noise_lag(diagnose: Mapping[str, Any], observations: Mapping[str, Any]) -> float:
    """Arc length (mm) over which the noise estimate differences the residual:
    ``diagnose.noise_lag`` if set, else :data:`IMAGE_NOISE_LAG_PIXELS` times the largest
    pixel size of the image files among the observations, else 0 (adjacent nodes)."""
    if diagnose.get("noise_lag") is not None:
        return float(diagnose["noise_lag"])
    sizes = _image_pixel_sizes(observations)
    return IMAGE_NOISE_LAG_PIXELS * max(sizes) if sizes else 0.0


def resolve_noise_model(diagnose: Mapping[str, Any], observations: Mapping[str, Any]) -> str:
    """Noise model of the predictive check's replicates
    (:data:`bayescalib.diagnosis.residuals.NOISE_MODELS`): ``diagnose.noise_model`` if
    set, else ``bootstrap`` for interfaces traced from images (their segmentation error
    is heavy-tailed and its level is estimated from ~100 nodes) when the check smooths
    (``diagnose.smoothing`` > 0: the bootstrap takes the smooth part out) and
    ``gaussian`` otherwise (synthetic coordinate noise, exactly i.i.d. Gaussian)."""
    if diagnose.get("noise_model") is not None:
        return str(diagnose["noise_model"])
    images = bool(_image_pixel_sizes(observations))
    return "bootstrap" if images and float(diagnose["smoothing"]) > 0 else "gaussian"


def thinned_observations(obs, spacing: float):
    """The observation set with every 2D snapshot thinned to one node per ``spacing`` mm
    of arc length (:func:`bayescalib.diagnosis.residuals.thin_nodes`; 0 = unchanged): the
    nodes the diagnosis uses when the noise is correlated along the interface (images).
    A 3D surface is kept whole (its nodes used: :func:`surface_nodes`)."""
    from bayescalib.diagnosis.residuals import thin_nodes
    from bayescalib.geometry.interface import Interface

    if spacing <= 0:
        return obs
    snaps = []
    for s in obs.snapshots:
        if s.dim == 3:
            snaps.append(s)
            continue
        pts = np.asarray(s.points)
        idx = thin_nodes(pts, spacing)
        snaps.append(Interface.polyline(pts[idx], closed=s.n_cells == s.n_points and idx.size >= 3,
                                        name=s.name))
    return dataclasses.replace(obs, snapshots=snaps)


#: the thinning spacing of a 3D surface's nodes, as a share of the smoothing length
#: (at least the noise correlation length): ~20 nodes within a kernel width
SURFACE_SPACING_SHARE = 0.5
#: most nodes of one surface the predictive check uses (its smoother is n x n): the
#: spacing grows by a quarter until the thinned nodes are fewer
MAX_SURFACE_NODES = 3000


def rim_height(surface, record: Mapping[str, Any] | None) -> float | None:
    """The height (mm) below which an observed surface segmented from an OCT volume is
    not used by the diagnosis: one voxel above the plane it was cut at.

    The layer of voxels just above the cut holds the colony's foot as the segmentation
    sees it, widened by the substrate's blur and chamfered onto the cut plane: on the
    example recording (``examples/oct_colony3d``, 6 um voxels) the segmented surface
    lies 4.1 um outside the true one in that layer (1.8 um with the floor given 36 um
    up) and 0.9-1.2 um outside in every layer above. The model cannot reproduce it, so
    the predictive check would locate a ring of "mismatch" around the foot of every
    colony. None: not a volume's surface (nothing left out)."""
    from bayescalib.io.observations import cut_height

    if not record or record.get("kind") != "volume":
        return None
    cut = cut_height(surface, record)
    return None if cut is None else float(cut) + float(record["voxel_size_mm"][1])


def surface_nodes(surface, spacing: float, above: float | None = None
                  ) -> tuple[np.ndarray, float]:
    """The nodes of an observed 3D surface the diagnosis uses: a Poisson-disk subset of
    its vertices at least ``spacing`` mm apart
    (:func:`bayescalib.diagnosis.residuals.thin_nodes`), the spacing grown by 25 % steps
    until at most :data:`MAX_SURFACE_NODES` remain; only the vertices at or above
    ``above`` (mm; :func:`rim_height`) when given.

    Returns
    -------
    nodes : ndarray, shape (n, 3)
        mm.
    spacing : float
        The spacing used, mm.
    """
    from bayescalib.diagnosis.residuals import thin_nodes

    pts = np.asarray(surface.points, dtype=float)
    if above is not None:
        pts = pts[pts[:, 1] >= above]
    h = float(spacing)
    if h <= 0:  # a spacing from the vertices' own density
        h = float(np.sqrt(surface.total_measure / MAX_SURFACE_NODES))
    idx = thin_nodes(pts, h)
    while idx.size > MAX_SURFACE_NODES:
        h *= 1.25
        idx = thin_nodes(pts, h)
    return pts[idx], h


def diagnosis_nodes(obs, lag: float, smoothing: float
                    ) -> tuple[list[np.ndarray], float | None]:
    """The observed nodes the diagnosis uses, per snapshot: a 2D curve's thinned to one
    per ``lag`` mm of arc length (:func:`thinned_observations`), a 3D surface's thinned
    to ``max(lag, SURFACE_SPACING_SHARE * smoothing)`` (:func:`surface_nodes`, above
    :func:`rim_height`).

    Returns
    -------
    nodes : list of ndarray
        (n_i, 2) or (n_i, 3), mm.
    spacing : float or None
        The 3D surfaces' thinning spacing, mm (None without a surface).
    """
    used = thinned_observations(obs, lag)
    nodes, spacing = [], None
    for s, rec in zip(used.snapshots, obs.segmentation or [None] * len(obs.snapshots),
                      strict=True):
        if s.dim == 3:
            pts, spacing = surface_nodes(s, max(lag, SURFACE_SPACING_SHARE * smoothing),
                                         rim_height(s, rec))
            nodes.append(pts)
        else:
            nodes.append(np.asarray(s.points, dtype=float))
    return nodes, spacing


@dataclass(frozen=True)
class DiagnosisContext:
    """What every step of the diagnosis needs (the module docstring).

    Attributes
    ----------
    fm : the validated ``forward_model`` section (``loadings`` included).
    parameters : the study's parameter list (its ``target``s are the points' columns).
    settings : the validated ``diagnose`` section.
    obs : the observation set as the diagnosis uses it (2D curves thinned to one node
        per ``noise_lag_mm``: :func:`thinned_observations`; 3D surfaces whole).
    nodes : per snapshot, the observed nodes the predictive checks and the attribution
        use, (n, 2) or (n, 3) mm: the thinned curve's, or a 3D surface's
        (:func:`surface_nodes`; a volume's without the layer of voxels above its cut,
        :func:`rim_height`).
    n_observed : the observed nodes per snapshot before thinning.
    surface_spacing_mm : the thinning spacing of the 3D surfaces' nodes (None in 2D).
    noise_lag_mm : the noise correlation length along the interface (:func:`noise_lag`).
    noise_model : the predictive check's noise model (:func:`resolve_noise_model`).
    segmentation_sigma : the segmentation's positional uncertainty of raw scans, mm (a
        lower bound of the noise; None: not segmented from scans).
    sigma : the observation noise sd given (``diagnose.noise_sigma``, else that of
        synthetic observations with noise), mm; None: estimated by each predictive check.
    work : the folder of the diagnosis's solves and extended calibrations.
    workers : solves at once.
    warm_start : the base state the solves start from (None: none).
    obs_path, measure_name, measure, likelihood : the observation store, the measure used
        and the validated ``measure`` and ``likelihood`` sections (an extended
        calibration's discrepancies).
    surrogate, smc_cfg, posterior_cfg, active : the validated ``surrogate``, ``smc``,
        ``posterior`` and ``design.active`` sections (an extended calibration's rounds).
    training_path : the training table of the study's calibration (its rows enter an
        extended calibration at ``phi = 0``).
    """

    fm: Mapping[str, Any]
    parameters: Sequence[Mapping[str, Any]]
    settings: Mapping[str, Any]
    obs: Any
    nodes: list[np.ndarray]
    n_observed: list[int]
    surface_spacing_mm: float | None
    noise_lag_mm: float
    noise_model: str
    segmentation_sigma: float | None
    sigma: float | None
    work: Path
    workers: int
    warm_start: str | Path | None
    obs_path: str | Path
    measure_name: str
    measure: Mapping[str, Any]
    likelihood: Mapping[str, Any]
    surrogate: Mapping[str, Any]
    smc_cfg: Mapping[str, Any]
    posterior_cfg: Mapping[str, Any]
    active: Mapping[str, Any]
    training_path: str | Path

    @classmethod
    def build(cls, *, diagnose: Mapping[str, Any], observations: Mapping[str, Any],
              obs_path: str | Path, outdir: str | Path, warm_start: str | Path | None,
              **sections: Any) -> DiagnosisContext:
        """The context of a diagnosis: reads the observation store (and the warm-start
        state, so that a damaged one is set aside and rebuilt before any solve starts
        from it), resolves the noise settings and thins the observed nodes.

        ``diagnose`` and ``observations`` are the validated sections; ``sections`` the
        remaining attributes as they are (``fm``, ``parameters``, ``measure_name``,
        ``measure``, ``likelihood``, ``surrogate``, ``smc_cfg``, ``posterior_cfg``,
        ``active``, ``training_path``, ``workers``).
        """
        from bayescalib.stages.files import read_stage_file

        obs = read_stage_file(obs_path, "observation set")
        if warm_start is not None:  # a damaged state is set aside and rebuilt, never solved from
            read_stage_file(warm_start, "warm-start state")
        lag = noise_lag(diagnose, observations)
        sigma = diagnose["noise_sigma"]
        if sigma is None and observations["source"] == "synthetic" \
                and float(observations["noise_sigma"]) > 0:
            sigma = float(observations["noise_sigma"])
        used = thinned_observations(obs, lag)
        nodes, spacing = diagnosis_nodes(obs, lag, float(diagnose["smoothing"]))
        return cls(settings=diagnose, obs=used, nodes=nodes,
                   n_observed=[len(s.points) for s in obs.snapshots],
                   surface_spacing_mm=spacing, noise_lag_mm=lag,
                   noise_model=resolve_noise_model(diagnose, observations),
                   # raw scans: the segmentation's positional uncertainty bounds the noise
                   # from below
                   segmentation_sigma=obs.segmentation_sigma(), sigma=sigma,
                   work=Path(outdir), warm_start=warm_start, obs_path=obs_path, **sections)

    @property
    def targets(self) -> list[str]:
        """The forward-model settings the parameters set (the points' columns)."""
        return [p["target"] for p in self.parameters]

    @property
    def names(self) -> list[str]:
        """The parameters' names (the posterior's)."""
        return [p["name"] for p in self.parameters]

    @property
    def dim(self) -> int:
        """The observed interfaces' dimension: 2 (curves) or 3 (surfaces)."""
        return int(self.nodes[0].shape[1])

    @property
    def n_snap(self) -> int:
        """The observed snapshots."""
        return len(self.obs.snapshots)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The parameters' box: lower and upper bounds."""
        from bayescalib.inference.parameters import ParameterSpace

        box = ParameterSpace.from_config(self.parameters).bounds
        return box[:, 0], box[:, 1]

    def solve(self, points: Sequence[Mapping[str, Any]], folder: str | Path) -> list:
        """Solve ``points`` by the solve path
        (:func:`bayescalib.models.forward.solve_points`) into ``<work>/<folder>/<k>.h5``
        (reused when the record exists with the same values)."""
        from bayescalib.models.forward import solve_points

        return solve_points(self.fm, points, [self.work / folder / f"{k}.h5"
                                              for k in range(len(points))],
                            workers=self.workers, warm_start=self.warm_start)

    def predictive_check(self, observed: Sequence[Any], curves: Sequence[Sequence[Any]],
                         sigma: float | None, seed: int):
        """The predictive check (:func:`bayescalib.diagnosis.residuals.predictive_check`)
        of the observed interfaces ``observed`` against the predictions ``curves`` of
        solved posterior draws, with the diagnosis's settings, the noise sd ``sigma``
        (None: estimated) and the noise replicates seeded by ``seed + 1``."""
        from bayescalib.diagnosis.residuals import predictive_check

        cfg = self.settings
        return predictive_check(observed, curves, labels=self.obs.labels, sigma=sigma,
                                noise_floor=cfg["noise_floor"], ell=cfg["smoothing"],
                                alpha=cfg["alpha"], n_noise=cfg["n_noise"],
                                noise_lag=self.noise_lag_mm, noise_model=self.noise_model,
                                segmentation_sigma=self.segmentation_sigma,
                                rng=np.random.default_rng(int(seed) + 1))

    def chain(self) -> dict[str, Any]:
        """The settings every extended calibration shares: the arguments of
        :func:`bayescalib.stages.chain.calibrate_rounds` beyond the model's own
        (:func:`bayescalib.diagnosis.extended.extended_calibration`)."""
        return {"obs_path": self.obs_path, "measure_name": self.measure_name,
                "measure": self.measure, "likelihood": self.likelihood,
                "surrogate": self.surrogate, "smc_cfg": self.smc_cfg,
                "posterior_cfg": self.posterior_cfg, "workers": self.workers,
                "warm_start": self.warm_start}
