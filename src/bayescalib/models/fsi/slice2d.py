"""The 2D model as a slice of a 3D flow cell: a B-scan study made from a 3D one.

A 2D (plane-strain) study of a 3D colony takes the mid-plane B-scan, ``z = z_c`` through
the colony's centre, and models it as a 2D flow cell: the channel's length and height,
the colony's section at rest, and an inflow per unit width. This module makes that
study from a 3D one (:func:`slice_study_config`) and the files it reads from a 3D
recording (:func:`write_surface_recording`: the surfaces as ``.vtp``, their mid-plane
sections as ``.csv``), so that the 2D model's error on a 3D colony can be measured
(``benchmarks/two_vs_three.py``, ``docs/two_vs_three.md``).

Geometry (:func:`midplane_geometry`). The plane ``z = z_c`` cuts the half-ellipsoid
``((x - x_c)/a)^2 + (y/b)^2 + ((z - z_c)/c)^2 <= 1`` in the half-ellipse of the same
length ``2a`` (``width``) and height ``b`` centred at ``x_c``: the 2D model's default
shape with the 3D colony's ``width``, ``height`` and ``centre``, in a channel of the
same ``length`` and ``channel_height``.

Inflow (:func:`slice_inflow_rate`). The 2D model's rate ``q`` (mm^2/s) is a flux per
unit width; a 3D rate ``Q`` (mm^3/s) has no unique 2D equivalent. Two mappings:

``mean_velocity``
    ``q = Q / W``: the same mean velocity (the same flux per unit width on average over
    the channel's width). Exact for a colony spanning the width with symmetry side
    walls (the ridge, ``geometry.side_walls: slip``), where the 3D solution is the 2D
    one (:mod:`bayescalib.models.fsi.geometry3d`).
``midplane_flux``
    ``q = Q q_duct(z_c) / Q_duct``: the flux per unit width of the developed duct flow
    through the line ``z = z_c`` upstream (:func:`bayescalib.models.fsi.duct.duct_flux_per_width`),
    i.e. the 2D model sees the upstream velocity profile of the slice it models (the
    flow a velocimetry of that plane would measure). No-slip side walls make the core
    faster than the mean: for a square duct at its middle ``q = 1.44 Q / W``. With slip
    side walls the profile is uniform in ``z`` and both mappings agree.

Neither accounts for the flow that goes around a colony of finite depth instead of
over it; that is the 2D model's error the benchmark measures.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.config import validate

__all__ = ["INFLOW_MAPPINGS", "midplane_geometry", "midplane_section", "midplane_z",
           "slice_inflow_rate", "slice_study_config", "write_surface_recording"]

#: the 3D-to-2D inflow mappings of :func:`slice_inflow_rate`
INFLOW_MAPPINGS = ("mean_velocity", "midplane_flux")


def _geometry_3d(geometry: Mapping[str, Any]) -> dict[str, Any]:
    """The validated 3D geometry section (defaults filled); refuses a 2D one."""
    geo = validate({"geometry": dict(geometry)}, "fsi", where="3D geometry")["geometry"]
    if int(geo["dim"]) != 3:
        raise ValueError("a 2D slice needs a 3D geometry (geometry.dim: 3)")
    if geo["shape"] not in ("half_ellipse", "ridge"):
        raise ValueError(f"a 2D slice of geometry.shape '{geo['shape']}' is not defined "
                         "(half_ellipse and ridge only)")
    return geo


def midplane_z(geometry: Mapping[str, Any]) -> float:
    """``z`` of the colony's mid-plane (``centre_z``, or the middle of the width; a
    scanned colony's, ``shape: scan``: the middle of its footprint's z-range, from
    ``height_field``, filled when the study is read), mm."""
    geo = validate({"geometry": dict(geometry)}, "fsi", where="3D geometry")["geometry"]
    if int(geo["dim"]) == 3 and geo["shape"] == "scan" and geo.get("height_field"):
        from bayescalib.models.fsi.scan3d import HeightField

        hf = HeightField.from_config(geo["height_field"])
        z = hf.z[np.any(hf.heights > 0, axis=0)]
        return 0.5 * float(z.min() + z.max()) if z.size else 0.5 * float(geo["channel_width"])
    geo = _geometry_3d(geometry)
    return 0.5 * float(geo["channel_width"]) if geo["centre_z"] is None \
        else float(geo["centre_z"])


def midplane_geometry(geometry: Mapping[str, Any]) -> dict[str, Any]:
    """The 2D model's geometry section for the mid-plane of a 3D colony.

    Parameters
    ----------
    geometry : mapping
        A 3D ``geometry`` section (``dim: 3``; defaults are filled).

    Returns
    -------
    dict
        ``{"dim": 2, "shape": "half_ellipse", "length", "channel_height", "width",
        "height", "centre"}`` (mm): the section of the half-ellipsoid (or the ridge) at
        rest through its centre, in a channel of the same length and height.
    """
    geo = _geometry_3d(geometry)
    return {"dim": 2, "shape": "half_ellipse", "length": float(geo["length"]),
            "channel_height": float(geo["channel_height"]), "width": float(geo["width"]),
            "height": float(geo["height"]), "centre": float(geo["centre"])}


def slice_inflow_rate(geometry: Mapping[str, Any], rate: float, mapping: str) -> float:
    """The 2D inflow rate (mm^2/s) of the mid-plane slice for a 3D rate (mm^3/s).

    Parameters
    ----------
    geometry : mapping
        The 3D ``geometry`` section.
    rate : float
        3D volume rate ``Q``, mm^3/s.
    mapping : {"mean_velocity", "midplane_flux"}
        ``Q / W``, or the developed duct flow's flux per unit width through the
        mid-plane (module docstring); with slip side walls both are ``Q / W``.

    Returns
    -------
    float
        ``q``, mm^2/s.
    """
    from bayescalib.models.fsi.duct import duct_flow_rate, duct_flux_per_width

    if mapping not in INFLOW_MAPPINGS:
        raise ValueError(f"inflow mapping: one of {', '.join(INFLOW_MAPPINGS)}, not {mapping!r}")
    geo = _geometry_3d(geometry)
    H, W = float(geo["channel_height"]), float(geo["channel_width"])
    if mapping == "mean_velocity" or geo["side_walls"] == "slip":
        return float(rate) / W
    return float(rate) * duct_flux_per_width(midplane_z(geo), H, W) / duct_flow_rate(H, W)


def midplane_section(surface: Any, geometry: Mapping[str, Any], *, name: str | None = None):
    """The mid-plane B-scan of a 3D interface: its section by ``z = z_c``.

    Parameters
    ----------
    surface : Interface
        A 3D triangulated interface (mm), e.g. a recorded colony surface.
    geometry : mapping
        The 3D ``geometry`` section (gives ``z_c``).
    name : str, optional
        Name of the section.

    Returns
    -------
    Interface
        The 2D curve ``(x, y)`` from the upstream to the downstream foot
        (:func:`bayescalib.geometry.surface.plane_section`).
    """
    from bayescalib.geometry.surface import plane_section

    return plane_section(surface, (0.0, 0.0, midplane_z(geometry)), (0.0, 0.0, 1.0), name=name)


def slice_study_config(config: Mapping[str, Any], sections: Sequence[str | Path],
                       mapping: str, *, study: str, mesh: str = "coarse",
                       scan: str | Path | None = None) -> dict[str, Any]:
    """The 2D study of a 3D study's mid-plane B-scans.

    Parameters
    ----------
    config : mapping
        A 3D study config (``forward_model.fsi.geometry.dim: 3``, ``observations.source:
        files``), as written (not validated).
    sections : sequence of path
        The mid-plane sections (``.csv``, mm) of the study's observation files, in the
        same order (one per loading).
    mapping : {"mean_velocity", "midplane_flux"}
        The inflow mapping (:func:`slice_inflow_rate`), applied to ``inflow.rate``,
        ``loadings.nominal`` and every file's ``load``.
    study : str
        Name of the 2D study.
    mesh : str
        The 2D model's mesh preset.
    scan : path, optional
        A zero-flow section (``.csv``, mm): the 2D colony is that outline
        (``geometry.shape: scan``) instead of the half-ellipse of
        :func:`midplane_geometry`.

    Returns
    -------
    dict
        The 2D study config: the same parameters, priors, measures, likelihood, design,
        surrogate and SMC; the forward model's other fsi keys (fluid, material law,
        solver) kept.
    """
    cfg = copy.deepcopy(dict(config))
    fm = cfg["forward_model"]
    fsi = dict(fm.get("fsi") or {})
    full = validate(fsi, "fsi", where="forward_model.fsi")
    geo3 = full["geometry"]
    if int(geo3["dim"]) != 3:
        raise ValueError("slice_study_config: the study's model is not 3D (geometry.dim: 3)")
    obs = cfg["observations"]
    if obs.get("source") != "files":
        raise ValueError("slice_study_config: the 3D study must read its observations from "
                         "files (observations.source: files)")
    files = list(obs.get("files") or [])
    if len(sections) != len(files):
        raise ValueError(f"slice_study_config: {len(sections)} section(s) for {len(files)} "
                         "observation file(s): give one section per file, in the same order")

    def rate2(q: float | None) -> float | None:
        return None if q is None else slice_inflow_rate(geo3, float(q), mapping)

    geo2 = midplane_geometry(geo3)
    if scan is not None:
        geo2 = {k: geo2[k] for k in ("dim", "length", "channel_height")}
        geo2.update(shape="scan", scan={"path": str(scan), "units": "mm"})
    fsi.update(geometry=geo2, mesh={"preset": mesh},
               inflow={**dict(fsi.get("inflow") or {}), "rate": rate2(full["inflow"]["rate"])})
    fm["fsi"] = fsi
    loadings = fm.get("loadings")
    if loadings and loadings.get("nominal") is not None:
        fm["loadings"] = {**loadings, "nominal": rate2(loadings["nominal"])}
    obs["files"] = [{**{k: v for k, v in e.items() if k not in ("path", "units", "load")},
                     "path": str(s), "units": "mm", "load": rate2(e.get("load"))}
                    for e, s in zip(files, sections, strict=True)]
    obs.pop("reference", None)
    if obs.get("domain"):
        obs["domain"] = [list(r) for r in obs["domain"][:2]]
    cfg["study"] = study
    cfg["description"] = (f"2D slice (mid-plane B-scans, inflow mapping {mapping}) of the 3D "
                          f"study {config.get('study')}")
    return cfg


def write_surface_recording(run: Any, geometry: Mapping[str, Any], out: str | Path, *,
                            noise_sigma: float, seed: int,
                            truth: Mapping[str, float]) -> dict[str, Any]:
    """Write a synthetic 3D recording: surfaces (``.vtp``) and mid-plane B-scans (``.csv``).

    The files a user of a volume scanner has: per loading of ``run`` the colony's surface
    with Gaussian coordinate noise (``load_<f>.vtp``, mm) and its section by the colony's
    mid-plane (``load_<f>.csv``, ``x,y`` in mm, upstream to downstream foot: the B-scan
    through the colony's centre, cut from the noisy surface), the same for the colony at
    rest (``rest.vtp``, ``rest.csv``), the noiseless surfaces (``truth_<label>.vtp``) for
    checking, and ``recording.json`` saying what is what.

    Parameters
    ----------
    run : SolveResult
        A 3D series solve (``loadings`` set; the reference surface is the colony at rest).
    geometry : mapping
        The 3D ``geometry`` section of the solve (gives the mid-plane).
    out : path
        Folder (created).
    noise_sigma : float
        Standard deviation of the coordinate noise, mm.
    seed : int
        Seed of the noise (one generator, rest first, then the loadings in order).
    truth : mapping
        The solve's parameters to record, e.g. ``{"material.E": 400, "material.nu": 0.3}``.

    Returns
    -------
    dict
        The contents of ``recording.json``: ``truth``, ``noise_sigma_mm``, ``seed``,
        ``midplane_z_mm``, ``rest`` and ``snapshots`` (label, loading factor, inflow rate
        mm^3/s, surface file, section file, truth file; paths relative to ``out``).
    """
    from bayescalib.geometry.interface import Interface
    from bayescalib.io.observations import add_noise, write_interface_csv, write_interface_vtk

    if not run.ok or not run.loadings:
        raise ValueError("write_surface_recording: needs a successful solve of a series of "
                         "loadings")
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    cells = np.asarray(run.segments)

    def record(points: np.ndarray, stem: str) -> dict[str, str]:
        clean = Interface(np.asarray(points, dtype=float), cells, name=stem)
        noisy = add_noise(clean, float(noise_sigma), rng)
        write_interface_vtk(folder / f"{stem}.vtp", noisy)
        write_interface_csv(folder / f"{stem}.csv", midplane_section(noisy, geometry, name=stem))
        write_interface_vtk(folder / f"truth_{stem}.vtp", clean)
        return {"surface": f"{stem}.vtp", "section": f"{stem}.csv", "truth": f"truth_{stem}.vtp"}

    info: dict[str, Any] = {
        "truth": {k: float(v) for k, v in truth.items()},
        "noise_sigma_mm": float(noise_sigma), "seed": int(seed),
        "midplane_z_mm": midplane_z(geometry), "geometry": _geometry_3d(geometry),
        "rest": record(run.interface_reference, "rest"), "snapshots": []}
    for ld in run.loadings:
        info["snapshots"].append({"label": ld.label, "factor": float(ld.factor),
                                  "inflow_rate_mm3_per_s": float(ld.value),
                                  **record(ld.current, ld.label)})
    (folder / "recording.json").write_text(json.dumps(info, indent=1) + "\n")
    return info
