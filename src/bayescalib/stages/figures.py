"""Figure stages of the pipeline: read the study's files, call :mod:`bayescalib.plotting`.

One function per figure family (one Snakemake rule each), so that changing a
plot setting reruns only the figures:

* :func:`response_figures` -- likelihood, log-likelihood and GP std over the
  design space with training points and failed runs (paper Figs. likexamples,
  loglikexamples, stdexamples). With more than two inputs, a 2-D slice through
  the first two calibrated inputs at the ground truth (else the box centre).
* :func:`convergence_figure` -- GP error over n_train (paper Fig. gpconv).
* :func:`posterior_figures` -- joint posterior with marginals, priors, MAP,
  PM, Gaussian and Laplace approximations; particles; 1-D marginals; pair
  marginals; parallel axes (paper Figs. sc_posteriors_twodim, 6D figures).
* :func:`interface_figure` -- undeformed, observed and posterior-sample interfaces.
* :func:`field_figure` -- velocity, pressure and displacement of the ground truth (synthetic
  data) or of the solve at the posterior mean (:func:`solve_at_posterior_mean`).
* :func:`rounds_figure` -- active design: posterior and solves per round, stop-rule checks.
* :func:`segmentation_figure` -- image observations with the interface traced from them,
  the floor and the threshold (studies with at least one image among the files).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.stages.files import read_stage_file

__all__ = [
    "convergence_figure",
    "field_figure",
    "interface_figure",
    "posterior_draws",
    "posterior_figures",
    "response_figures",
    "rounds_figure",
    "segmentation_figure",
]


def _space(parameters):
    from bayescalib.inference.parameters import ParameterSpace

    return ParameterSpace.from_config(parameters)


def _paths(stem: str | Path, formats: Sequence[str]) -> list[str]:
    return [f"{stem}.{fmt}" for fmt in formats]


def _prior_pdf(p):
    """The prior density of parameter ``p`` as a function of an array of values."""
    return lambda x: np.exp(p.logpdf(np.asarray(x, float)))


def _labels(space) -> tuple[list[str], list[str]]:
    greek = {"nu": "ν", "theta": "θ"}
    names = [greek.get(n, n) for n in space.names]
    return names, list(space.units)


def response_figures(training_path: str | Path, surrogate_path: str | Path,
                     parameters: Sequence[Mapping[str, Any]], plots: Mapping[str, Any],
                     stem: str | Path) -> list[str]:
    """Response surfaces of the GP log-likelihood over two inputs."""
    from bayescalib.plotting import plot_response_surface

    space = _space(parameters)
    tab = read_stage_file(training_path, "training table")
    gp = read_stage_file(surrogate_path, "surrogate")
    d = space.dim
    if d < 2:
        raise ValueError("response surfaces need at least two inputs")
    ix, iy = _shown_pair(space)
    b = space.bounds
    n = int(plots["grid"])
    gx = np.linspace(b[ix, 0], b[ix, 1], n)
    gy = np.linspace(b[iy, 0], b[iy, 1], n)
    base = space.ground_truth if space.ground_truth is not None else b.mean(axis=1)
    XX, YY = np.meshgrid(gx, gy)
    pts = np.tile(base, (XX.size, 1))
    pts[:, ix] = XX.ravel()
    pts[:, iy] = YY.ravel()
    mean, var = gp.predict(pts, return_var=True)
    tr = tab["is_train"].astype(bool)
    ok = tab["status"].astype(bool)
    X = tab["X"]
    names, units = _labels(space)
    truth = None if space.ground_truth is None else [space.ground_truth[ix], space.ground_truth[iy]]
    title = None
    if d > 2:
        others = [f"{space.names[k]} = {base[k]:.3g}" for k in range(d) if k not in (ix, iy)]
        title = "slice at " + ", ".join(others)
    return plot_response_surface(
        gx, gy, mean.reshape(n, n), np.sqrt(np.maximum(var, 0.0)).reshape(n, n),
        X[tr & ok][:, [ix, iy]], X[tr & ~ok][:, [ix, iy]],
        [names[ix], names[iy]], [units[ix], units[iy]],
        _paths(stem, plots["formats"]), truth=truth, title=title, dpi=plots["dpi"],
    )


def convergence_figure(convergence_path: str | Path, plots: Mapping[str, Any],
                       stem: str | Path) -> list[str]:
    """GP error over the number of training points."""
    from bayescalib.plotting import plot_gp_convergence

    res = read_stage_file(convergence_path, "GP convergence record")
    n = np.asarray(res["n_train"], float)
    rel = np.asarray(res["rel_error"], float)
    loo = np.asarray(res["loo_rel_error"], float)
    return plot_gp_convergence(
        n, rel, loo if np.all(np.isfinite(loo)) else None,
        _paths(stem, plots["formats"]), relative=True, dpi=plots["dpi"],
    )


def _levels(post: Mapping[str, Any]) -> tuple[float, ...]:
    """The credible levels the summary was made at (posterior.levels): the joint
    figure's contours are drawn at the same levels as the intervals reported."""
    per_parameter = next(iter(post["intervals"].values()))
    return tuple(sorted(float(k) for k in per_parameter))


def posterior_figures(particles_path: str | Path, posterior_path: str | Path,
                      parameters: Sequence[Mapping[str, Any]], plots: Mapping[str, Any],
                      stems: Mapping[str, str | Path]) -> dict[str, list[str]]:
    """Joint, particles, 1-D marginals, pair marginals and parallel-axis figures.

    ``stems`` maps ``joint``, ``particles``, ``marginals``, ``pairs``,
    ``parallel`` to output stems (without suffix); a family without a stem is not
    drawn (the workflow draws pairs and parallel axes from three parameters on: for
    two, the joint figure shows all they would).
    """
    from bayescalib.plotting import (
        plot_joint_posterior,
        plot_marginals_1d,
        plot_pair_marginals,
        plot_parallel_axes,
        plot_particles,
    )

    space = _space(parameters)
    res = read_stage_file(particles_path, "SMC particle file")
    post = read_stage_file(posterior_path, "posterior summary")
    X = np.asarray(res.particles)
    W = np.asarray(res.weights)
    names, units = _labels(space)
    fmt = plots["formats"]
    dpi = plots["dpi"]
    b = space.bounds
    truth = space.ground_truth
    prior_pdfs = [_prior_pdf(p) for p in space.parameters]
    mean_all = np.array([post["mean"][n] for n in space.names])
    map_all = np.array([post["map_full"][n] for n in space.names])
    out: dict[str, list[str]] = {}

    cal = [i for i in range(space.dim) if space.calibrated_mask[i]]
    pair = (cal + [i for i in range(space.dim) if i not in cal])[:2]
    if len(pair) == 2:
        i, j = pair
        cal_names = post["gaussian"]["names"]

        def sub_gauss(g):
            if not g or g.get("mean") is None or g.get("cov") is None:
                return None
            gn = g.get("names", cal_names)
            if space.names[i] not in gn or space.names[j] not in gn:
                return None
            a, c = gn.index(space.names[i]), gn.index(space.names[j])
            m = np.asarray(g["mean"], float)[[a, c]]
            C = np.asarray(g["cov"], float)[np.ix_([a, c], [a, c])]
            if not np.all(np.isfinite(C)) or np.any(np.linalg.eigvalsh(C) <= 0):
                return None
            return (m, C)

        out["joint"] = plot_joint_posterior(
            X[:, [i, j]], W, [names[i], names[j]], [units[i], units[j]],
            _paths(stems["joint"], fmt), prior_pdfs=(prior_pdfs[i], prior_pdfs[j]),
            map=map_all[[i, j]], mean=mean_all[[i, j]], gaussian=sub_gauss(post.get("gaussian")),
            laplace=sub_gauss(post.get("laplace")),
            levels=_levels(post),
            truth=None if truth is None else truth[[i, j]], bounds=b[[i, j]], dpi=dpi,
        )
        out["particles"] = plot_particles(
            X[:, [i, j]], W, [names[i], names[j]], [units[i], units[j]],
            _paths(stems["particles"], fmt), bounds=b[[i, j]],
            truth=None if truth is None else truth[[i, j]], dpi=dpi,
        )
    out["marginals"] = plot_marginals_1d(
        X, W, names, units, _paths(stems["marginals"], fmt), prior_pdfs=prior_pdfs,
        map=map_all, mean=mean_all, truth=truth, bounds=b, dpi=dpi,
    )
    if "pairs" in stems:
        out["pairs"] = plot_pair_marginals(
            X, W, names, units, _paths(stems["pairs"], fmt), truth=truth, bounds=b, dpi=dpi,
        )
    if "parallel" in stems:
        logpost = np.asarray(res.loglik) + np.asarray(res.logprior)
        out["parallel"] = plot_parallel_axes(
            X, logpost, names, units, _paths(stems["parallel"], fmt), values_are_log=True,
            value_name="log posterior density", bounds=b, dpi=dpi,
        )
    return out


def posterior_draws(particles_path: str | Path, parameters: Sequence[Mapping[str, Any]],
                    k: int, n: int, seed: int) -> dict[str, float]:
    """Draw ``k`` of ``n`` equally weighted posterior draws, keyed by target.

    The ``n`` draws are a systematic resample of the final SMC particles with
    a generator seeded by ``seed``, so draw ``k`` is the same in every job.
    """
    from bayescalib.inference.posterior import equal_weight_draws

    x = equal_weight_draws(read_stage_file(particles_path, "SMC particle file"), n,
                           seed)[int(k)]
    targets = [p["target"] for p in parameters]
    return {t: float(v) for t, v in zip(targets, x, strict=True)}


def interface_figure(obs_path: str | Path, sample_runs: Sequence[str | Path],
                     plots: Mapping[str, Any], stem: str | Path,
                     ground_truth_run: str | Path | None = None) -> list[str]:
    """Undeformed, observed and posterior-sample interfaces. 3D surfaces are shown by
    their section with the plane z = z0 through the middle of the observed colony
    (:func:`bayescalib.geometry.surface.plane_section`, the B-scan a 2D model sees), and
    the last observed surface rendered beside it, coloured by its signed distance from
    the first posterior sample's surface at that loading (where the model misses the
    data: + out of the model's colony), or without samples from the undeformed one."""
    from bayescalib.geometry.interface import Interface
    from bayescalib.plotting import plot_interfaces

    obs = read_stage_file(obs_path, "observation set")
    first = obs.snapshots[0]
    z0 = None if first.dim == 2 else float(0.5 * (first.points[:, 2].min()
                                                 + first.points[:, 2].max()))

    def shown(points: np.ndarray, cells: np.ndarray, name: str) -> np.ndarray:
        if z0 is None:
            return np.asarray(points)
        from bayescalib.geometry.surface import plane_section

        return np.asarray(plane_section(Interface(points, cells, name=name),
                                        (0.0, 0.0, z0)).points)

    samples, ref, first_run = [], None, None
    for rp in sample_runs:
        run = read_stage_file(rp, "run record")
        if run.status == "ok":
            samples.append(shown(run.interface_current, run.segments, str(rp)))
            if ref is None:
                ref = shown(run.interface_reference, run.segments, str(rp))
                first_run = run
    if obs.reference is not None:
        ref = shown(obs.reference.points, obs.reference.cells, "reference")
    if ref is None:
        ref = shown(first.points, first.cells, obs.labels[0])
    truth = None
    if ground_truth_run is not None:
        gt = read_stage_file(ground_truth_run, "run record")
        if gt.status == "ok":
            truth = shown(gt.interface_current, gt.segments, "ground truth")
    surface = None
    if z0 is not None:
        from bayescalib.geometry.projection import closest_points
        from bayescalib.stages.discrepancy import model_interfaces

        last = obs.snapshots[-1]
        if first_run is not None:
            against = model_interfaces(first_run, len(obs.snapshots), obs.cut_heights())[-1]
            what = f"from posterior sample 1 at {obs.labels[-1]}"
        else:
            against = Interface(obs.reference.points, obs.reference.cells) \
                if obs.reference is not None else last
            what = "from the undeformed surface"
        d = closest_points(last.points, against)[0]
        surface = (last.points, last.cells, 1e3 * d,
                   f"observed surface {obs.labels[-1]}: distance {what} [um]")
    return plot_interfaces(
        ref, [shown(s.points, s.cells, lb) for s, lb in zip(obs.snapshots, obs.labels)],
        samples, _paths(stem, plots["formats"]), truth_interface=truth, dpi=plots["dpi"],
        title=None if z0 is None else f"section z = {z0:.3g} mm of the 3D interfaces",
        surface=surface)


def segmentation_figure(obs_path: str | Path, observations: Mapping[str, Any],
                        plots: Mapping[str, Any], stem: str | Path) -> list[str]:
    """Each image observation in grey with the interface traced from it and its floor.

    The traced interfaces and what the segmentation did (threshold, floor, pixel size,
    origin, uncertainty) come from ``observations.h5`` (the observe job's record, one
    per snapshot, in the order of ``observations.files``); the grey values are read
    again from the image files.
    """
    from bayescalib.geometry.imaging import read_image
    from bayescalib.plotting import plot_segmentation

    obs = read_stage_file(obs_path, "observation set")
    segs = obs.segmentation or [None] * len(obs.snapshots)
    files = list(observations.get("files") or [])
    panels = [(k, e, segs[k]) for k, e in enumerate(files)
              if k < len(segs) and segs[k] is not None]
    if not panels:
        raise ValueError(f"{obs_path}: no snapshot was read from an image: no segmentation "
                         "figure to draw")
    images, curves, sizes, origins, floors, labels, thr, how, sig = ([] for _ in range(9))
    for k, entry, seg in panels:
        images.append(read_image(entry["path"])[0])
        curves.append(np.asarray(obs.snapshots[k].points))
        sizes.append(seg["pixel_size_mm"])
        origins.append(seg["origin_mm"])
        floors.append(seg.get("floor_mm"))
        labels.append(f"{obs.labels[k]} ({seg['kind']})")
        thr.append(seg.get("threshold"))
        how.append(seg.get("threshold_method"))
        sig.append(seg.get("sigma_mm"))
    return plot_segmentation(images, curves, _paths(stem, plots["formats"]),
                             pixel_sizes=sizes, origins=origins, floors=floors, labels=labels,
                             thresholds=thr, threshold_methods=how, sigmas=sig,
                             dpi=plots["dpi"])


def read_vtu_fields(path: str | Path) -> dict[str, np.ndarray]:
    """Points, cells and point fields of a VTU written by the FSI model
    (:func:`bayescalib.models.fsi.vtu.write_fields_vtu`).

    2D (triangles): ``points`` (p, 2), ``triangles`` (t, 3), ``velocity`` and
    ``displacement`` (p, 2), ``pressure`` (p,), ``region`` (t,). 3D (tetrahedra):
    ``points`` (p, 3), ``tetrahedra`` (t, 4), ``velocity`` and ``displacement`` (p, 3),
    ``pressure`` (p,), ``region`` (t,).
    """
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(path))
    r.Update()
    grid = r.GetOutput()
    if grid is None or grid.GetNumberOfPoints() == 0:
        raise ValueError(f"VTU file '{path}' is empty or unreadable")
    dim = 3 if grid.GetNumberOfCells() and grid.GetCellType(0) == vtk.VTK_TETRA else 2
    pts = vtk_to_numpy(grid.GetPoints().GetData())[:, :dim]
    cells = vtk_to_numpy(grid.GetCells().GetConnectivityArray()).reshape(-1, dim + 1)
    pd = grid.GetPointData()
    out = {"points": pts, "triangles" if dim == 2 else "tetrahedra": cells}
    for name in ("velocity", "pressure", "displacement"):
        arr = pd.GetArray(name)
        if arr is None:
            raise ValueError(f"VTU file '{path}' has no point array '{name}'")
        a = vtk_to_numpy(arr)
        out[name] = a[:, :dim] if a.ndim == 2 else a
    reg = grid.GetCellData().GetArray("region")
    out["region"] = vtk_to_numpy(reg) if reg is not None else np.zeros(len(cells))
    return out


#: the six edges of a tetrahedron, in its local nodes
_TET_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))


def section_fields(fields: Mapping[str, np.ndarray], z: float) -> dict[str, np.ndarray]:
    """The section of 3D fields (:func:`read_vtu_fields` of a tetrahedral VTU) by the
    plane ``z = z`` (on the points as they are, i.e. the deformed mesh), interpolated
    linearly on the tetrahedra: what a B-scan at ``z`` sees, as 2D fields.

    Each tetrahedron the plane crosses gives a triangle (one or three of its nodes
    below the plane) or a quadrilateral cut into two (two below); nodes exactly on the
    plane count as above it, so a face in the plane is drawn once, and a point is shared
    by the cut tetrahedra through the edge (or the node) it lies on.

    Returns
    -------
    dict
        ``points`` (p, 2) the in-plane coordinates (x, y); ``triangles`` (t, 3);
        ``velocity`` and ``displacement`` (p, 3) (all three components); ``pressure``
        (p,); ``region`` (t,) the region of the tetrahedron each triangle is cut from.

    Raises
    ------
    ValueError
        When the plane misses the mesh.
    """
    pts = np.asarray(fields["points"], dtype=float)
    tets = np.asarray(fields["tetrahedra"], dtype=np.int64)
    s = pts[:, 2] - float(z)
    # nodes within a nanometre-scale tolerance of the plane are on it (a mesh symmetric
    # about the plane has nodes there up to rounding; left apart they give duplicate
    # points a few ulp apart and slivers)
    s[np.abs(s) <= 1e-8 * max(float(np.ptp(pts[:, 2])), 1.0)] = 0.0
    below = s[tets] < 0
    nb = below.sum(axis=1)
    cut = (nb > 0) & (nb < 4)
    if not cut.any():
        raise ValueError(f"the plane z = {z:g} misses the mesh "
                         f"(z in [{pts[:, 2].min():g}, {pts[:, 2].max():g}])")
    tets, below, nb = tets[cut], below[cut], nb[cut]
    region = np.asarray(fields["region"])[cut]
    m = len(tets)
    # the crossing edges: (below node, above node), global; a point on the plane (the
    # above node with s == 0) is keyed by that node alone, so that all its edges share it
    lo_list, hi_list, slot_list = [], [], []
    for e, (i, j) in enumerate(_TET_EDGES):
        cross = np.flatnonzero(below[:, i] != below[:, j])
        bi = np.where(below[cross, i], tets[cross, i], tets[cross, j])
        ai = np.where(below[cross, i], tets[cross, j], tets[cross, i])
        lo_list.append(bi)
        hi_list.append(ai)
        slot_list.append(np.column_stack([cross, np.full(len(cross), e)]))
    b, a = np.concatenate(lo_list), np.concatenate(hi_list)
    slot = np.concatenate(slot_list)
    on_plane = s[a] == 0
    keys = np.column_stack([np.where(on_plane, -1, b), a])
    _, first, inv = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    t = s[b[first]] / (s[b[first]] - s[a[first]])

    def interp(v):
        v = np.asarray(v, dtype=float)
        tt = t if v.ndim == 1 else t[:, None]
        return v[b[first]] + tt * (v[a[first]] - v[b[first]])

    point_of = np.full((m, 6), -1, dtype=np.int64)  # per tet and local edge
    point_of[slot[:, 0], slot[:, 1]] = inv
    edge_no = {pair: e for e, pair in enumerate(_TET_EDGES)}

    # local nodes, the ones below first
    order = np.argsort(~below, axis=1, kind="stable")
    tris, reg = [], []
    for n_below, combos in ((1, [[(0, 1), (0, 2), (0, 3)]]),
                            (3, [[(0, 3), (1, 3), (2, 3)]]),
                            (2, [[(0, 2), (0, 3), (1, 3)], [(0, 2), (1, 3), (1, 2)]])):
        sel = np.flatnonzero(nb == n_below)
        if not sel.size:
            continue
        o = order[sel]
        for combo in combos:
            tri = np.empty((sel.size, 3), dtype=np.int64)
            for c, (p, q) in enumerate(combo):
                lp, lq = o[:, p], o[:, q]
                e = np.empty(sel.size, dtype=np.int64)
                for (i, j), k in edge_no.items():
                    e[((lp == i) & (lq == j)) | ((lp == j) & (lq == i))] = k
                tri[:, c] = point_of[sel, e]
            tris.append(tri)
            reg.append(region[sel])
    tri = np.vstack(tris)
    reg = np.concatenate(reg)
    # a triangle through a node on the plane may collapse (two corners that node)
    ok = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
    xyz = interp(pts)
    return {"points": xyz[:, :2], "triangles": tri[ok], "region": reg[ok],
            "velocity": interp(fields["velocity"]), "displacement": interp(fields["displacement"]),
            "pressure": interp(fields["pressure"])}


def posterior_mean_point(posterior_path: str | Path,
                         parameters: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """The posterior mean of a study (its ``posterior.json``), keyed by target: the
    values at which the fields of the calibrated model are solved."""
    mean = read_stage_file(posterior_path, "posterior summary")["mean"]
    return {p["target"]: float(mean[p["name"]]) for p in parameters}


def solve_at_posterior_mean(posterior_path: str | Path, parameters: Sequence[Mapping[str, Any]],
                            forward_model: Mapping[str, Any], out_path: str | Path,
                            vtu_path: str | Path) -> None:
    """Forward solve at the posterior mean with its fields (the fsi model's VTU), the
    same solve as every other (:func:`bayescalib.models.forward.solve_points`).

    A failed solve leaves its run record (with the reason) and an empty ``vtu_path``;
    :func:`field_figure` then draws the reason instead of the fields.
    """
    from bayescalib.models.forward import solve_points

    point = posterior_mean_point(posterior_path, parameters)
    res = solve_points(forward_model, [point], [out_path], extra_outputs=[{"vtu": str(vtu_path)}],
                       reuse=False)[0]
    if res.status != "ok" or not Path(vtu_path).is_file():
        Path(vtu_path).write_bytes(b"")


def _at_posterior_mean_title(run, parameters: Sequence[Mapping[str, Any]]) -> str:
    """"Fields at the posterior mean: E = 412 Pa, nu = 0.31" from the run record."""
    parts = []
    for p in parameters:
        v = run.parameters.get(p["target"])
        unit = "" if p["unit"] in ("-", "", "1") else f" {p['unit']}"
        if v is not None:
            parts.append(f"{p['name']} = {float(v):.4g}{unit}")
    return "Fields at the posterior mean" + (f": {', '.join(parts)}" if parts else "")


def field_figure(vtu_path: str | Path, run_path: str | Path, plots: Mapping[str, Any],
                 stem: str | Path, *, at: str | None = None,
                 parameters: Sequence[Mapping[str, Any]] | None = None,
                 section_z: float | None = None) -> list[str]:
    """Velocity, pressure and displacement fields of one forward solve.

    Parameters
    ----------
    vtu_path, run_path
        The solve's fields (VTU) and run record.
    plots
        The ``plots`` section (formats, dpi).
    stem
        Output path without suffix.
    at
        None: the solve at the ground truth (synthetic data; no title). ``"posterior_mean"``:
        the solve at the posterior mean (titled so, with its values); when that solve
        failed the figure says why instead.
    parameters
        The ``parameters`` section (names and units of the title), with ``at``.
    section_z
        3D fields: ``z`` of the plane they are shown in (mm; the colony's mid-plane,
        the plane of a B-scan, :func:`bayescalib.models.fsi.slice2d.midplane_z`). None:
        the middle of the z range of the colony's surface at rest. The figure is that of
        a 2D model in the section (:func:`section_fields`), with the interface's section
        (:func:`bayescalib.geometry.surface.plane_section`), the magnitudes those of the
        3D vectors and the streamlines those of the in-plane velocity. Ignored in 2D.
    """
    from bayescalib.plotting import plot_fields
    from bayescalib.plotting.fields import plot_failed_solve

    title = None
    if at is not None:
        if at != "posterior_mean":
            raise ValueError(f"field_figure: at must be None or 'posterior_mean', got {at!r}")
        run = read_stage_file(run_path, "run record")
        title = _at_posterior_mean_title(run, parameters or [])
        if run.status != "ok":
            return plot_failed_solve(_paths(stem, plots["formats"]), title,
                                     f"The forward solve at the posterior mean failed: "
                                     f"{run.reason or 'no reason recorded'}", dpi=plots["dpi"])
    f = read_stage_file(vtu_path, "VTU field file")
    run = read_stage_file(run_path, "run record")
    interface = np.asarray(run.interface_current)
    if "tetrahedra" in f:
        f, interface, z = _section(f, run, section_z)
        where = f"section z = {z:.4g} mm through the colony"
        title = where[0].upper() + where[1:] if title is None else f"{title}\n{where}"
    return plot_fields(
        f["points"], f["triangles"], f["velocity"], f["pressure"], f["displacement"],
        _paths(stem, plots["formats"]), interface=interface,
        solid_mask_triangles=f["region"] > 0, title=title, dpi=plots["dpi"],
    )


def _section(fields: Mapping[str, np.ndarray], run, z: float | None):
    """3D fields and interface in the plane ``z`` (:func:`field_figure`): the section's
    fields, the interface's section (None where the plane misses it) and ``z``."""
    from bayescalib.geometry.interface import Interface
    from bayescalib.geometry.surface import SurfaceError, plane_section

    if z is None:
        ref = np.asarray(run.interface_reference)
        z = 0.5 * float(ref[:, 2].min() + ref[:, 2].max())
    z = float(z)
    sec = section_fields(fields, z)
    try:
        surface = Interface(np.asarray(run.interface_current), np.asarray(run.segments))
        curve = np.asarray(plane_section(surface, (0.0, 0.0, z)).points)
    except (SurfaceError, ValueError):
        curve = None
    return sec, curve, z


def _shown_pair(space, posterior_sd: Sequence[float] | None = None) -> list[int]:
    """Indices of the two inputs shown in 2-D figures (in the parameters' order).

    Without ``posterior_sd``: the first two calibrated inputs (then uncertain
    conditions). With it: the two calibrated inputs the data identify best, i.e. with
    the smallest posterior sd relative to their box width (in 6 or more dimensions the
    first two are often ones the data say nothing about)."""
    d = space.dim
    cal = [i for i in range(d) if space.calibrated_mask[i]]
    order = cal + [i for i in range(d) if i not in cal]
    if posterior_sd is None or len(cal) < 2:
        return order[:2]
    width = space.bounds[:, 1] - space.bounds[:, 0]
    rel = np.asarray(posterior_sd, float) / width
    best = sorted(cal, key=lambda i: (rel[i], i))[:2]
    return sorted(best)


def rounds_figure(acquire_paths: Sequence[str | Path], particles_paths: Sequence[str | Path],
                  training_path: str | Path, parameters: Sequence[Mapping[str, Any]],
                  active: Mapping[str, Any], plots: Mapping[str, Any],
                  stem: str | Path) -> list[str]:
    """Active design rounds (posterior draws, solves, chosen batches) and the stop
    rule's checks per round; needs at least two parameters."""
    from bayescalib.inference.posterior import equal_weight_draws
    from bayescalib.plotting.rounds import plot_rounds

    space = _space(parameters)
    if space.dim < 2:
        raise ValueError("the rounds figure needs at least two parameters")
    recs = [read_stage_file(p, "active round record") for p in acquire_paths]
    ix = _shown_pair(space, recs[-1]["posterior"]["sd"])
    draws = [equal_weight_draws(read_stage_file(p, "SMC particle file"), 600, 0)[:, ix]
             for p in particles_paths]
    tab = read_stage_file(training_path, "training table")
    X = tab["X"][:, ix]
    failed = X[tab["status"] == 0]
    batches = [np.asarray(r["next"]["points"], float)[:, ix] if "next" in r else None
               for r in recs]
    names, units = _labels(space)
    truth = None if space.ground_truth is None else space.ground_truth[ix]
    return plot_rounds(
        draws, X, [r["n_solves"] for r in recs], batches,
        [None if r["change"] is None else r["change"]["shift_sd"] for r in recs],
        [None if r["trust"] is None else r["trust"]["max_abs_error"] for r in recs],
        [names[i] for i in ix], [units[i] for i in ix], _paths(stem, plots["formats"]),
        bounds=space.bounds[ix], shift_tol=active["stop"]["shift_tol"],
        gp_tol=active["stop"]["gp_tol"], converged=bool(recs[-1]["converged"]),
        truth=truth, failed=failed, dpi=plots["dpi"],
        batch_kinds=[r["next"].get("kind") if "next" in r else None for r in recs],
        posterior_check=[r.get("posterior_check") for r in recs],
    )
