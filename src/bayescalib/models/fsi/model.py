"""The biofilm flow-cell forward model: config -> mesh -> solve -> run record.

:class:`FSIModel` wraps the solver core (:mod:`bayescalib.models.fsi.solver`) for the problem of
paper Sec. 4.1 / App. B: a 2 mm x 1 mm channel with a biofilm patch on the floor, a
parabolic inflow of volume rate ``inflow.rate`` (mm^2/s) on the left, no-slip on floor,
top and biofilm base, do-nothing outflow on the right, St. Venant–Kirchhoff (or
compressible neo-Hooke) biofilm in plane strain with E, nu per subdomain.

3D (``geometry.dim: 3``). The same model class, solver core and weak form
(:mod:`bayescalib.models.fsi.solver` is written for any dimension) on the 3D flow cell
of :mod:`bayescalib.models.fsi.geometry3d`: a rectangular channel (length x, height y,
width z) with a half-ellipsoidal colony on the floor, the full 3D laws of
:mod:`bayescalib.models.fsi.materials`, the developed rectangular-duct inflow profile
(:mod:`bayescalib.models.fsi.duct`) of volume rate ``inflow.rate`` (mm^3/s), no-slip on
floor, top and side walls (or symmetry side walls, ``geometry.side_walls: slip``),
do-nothing outflow. Its interface is a triangulated surface: ``interface_reference`` and
``interface_current`` are (n, 3), ``segments`` holds the (m, 3) triangles (normals into
the fluid). It has all the candidate physics (:data:`PHYSICS_3D`: the same forms as
in 2D, gravity with three components, the skewed inflow on the duct profile, the
attachment springs in x and z with the base and the floor's ALE mesh sliding in both,
:func:`_sliding_base`) and its own mesh presets (:data:`MESH_PRESETS_3D`). The 3D model is a value of the existing section rather than
a new model type, so that everything else of the section (fluid, material, inflow,
solver, the warm starts and series of loadings) and the one solve path
(:func:`bayescalib.models.forward.solve_points`) serve both unchanged.

Units. Config and outputs use mm, Pa, mm^2/s (density kg/m^3, viscosity Pa s). The
solver works in mm, s, mg, where water has rho = 1 mg/mm^3 and mu = 1 mg/(mm s) and
stresses are in mPa: E = 400 Pa is 4e5 in solver units (factor :data:`PA`).

Mesh and geometry are built once per model object and reused for every solve whose
geometry/mesh/law keys are unchanged (material values and the inflow rate are NGSolve
parameters / boundary data, so nothing is recompiled). The initial state of a solve is
rest (continuation from zero inflow) unless a warm start is given: a state file saved by
:meth:`FSIModel.save_state` (e.g. the base state at the prior centre), a state vector, or
the in-memory last state (``warm_start="last"``); it is used as initial guess at the
full load, and the solve falls back to the continuation from rest if Newton fails from
it. A warm-started solve in the same model object also starts with the LU
factorization kept from the previous solve (``solver.keep_factorization``): chord steps
only, re-factorized as soon as they stop contracting — for a sequence of nearby
parameters no factorization is needed at all (see ``benchmarks/bench_fsi.py``).

Outputs: :class:`bayescalib.io.runrecord.SolveResult` with the interface vertices ordered
from the upstream to the downstream foot (2D; in 3D the surface's vertices and
triangles; reference and deformed, mm), parameters in
user units and solver statistics (DOFs, factorizations, phase timings, ``min_det_F``,
``max_interface_velocity`` as a slip check).
"""

from __future__ import annotations

import copy
import hashlib
import json
import resource
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.config import ConfigError, set_dotted, validate
from bayescalib.io._atomic_write import atomic_path
from bayescalib.io.runrecord import SolveResult
from bayescalib.models.fsi.geometry import SOLID_SUBDOMAINS, BiofilmMesh, build_mesh
from bayescalib.models.fsi.materials import poisson_problem
from bayescalib.models.fsi.physics import (
    CANDIDATES,
    SolidPhysics,
    physics_parameters,
    physics_problem,
    springs_active,
    unsupported_combination,
)
from bayescalib.models.fsi.problem import FSIProblem
from bayescalib.models.fsi.solver import MonolithicSolver, SolverControls

__all__ = ["MESH_PRESETS", "MESH_PRESETS_3D", "PA", "PHYSICS_3D", "FSIModel", "dim3_problem", "finer_preset",
           "fsi_section"]

#: Pa -> solver stress units mg/(mm s^2) (= mPa)
PA = 1.0e3
#: kg/m^3 -> mg/mm^3
KG_PER_M3 = 1.0e-3
#: Pa s -> mg/(mm s)
PA_S = 1.0e3
#: mesh presets (sizes in mm). ``paper`` has 65 interface nodes (paper: 66) and a mesh
#: graded quickly away from the interface: the same interface accuracy as a uniformly
#: fine bulk (1.0e-4 mm against ``fine``) with half the unknowns. ``fine`` (130 nodes,
#: slow grading) is the reference for mesh-convergence checks.
MESH_PRESETS = {
    "paper": {"h_interface": 0.017, "h_bulk": 0.12, "h_solid": 0.06, "grading": 0.7},
    "coarse": {"h_interface": 0.035, "h_bulk": 0.16, "h_solid": 0.07, "grading": 0.5},
    "very_coarse": {"h_interface": 0.07, "h_bulk": 0.25, "h_solid": 0.1, "grading": 0.5},
    "fine": {"h_interface": 0.0085, "h_bulk": 0.04, "h_solid": 0.017, "grading": 0.3},
}
#: mesh presets of the 3D flow cell (``geometry.dim: 3``; tetrahedra, sizes in mm), sized
#: for one core of a 2-core machine (``benchmarks/bench_fsi3d.py`` measures them):
#: ``very_coarse`` solves in seconds (tests), ``coarse`` in about a minute, ``paper`` in
#: a few. There is no 3D ``fine``.
MESH_PRESETS_3D = {
    "very_coarse": {"h_interface": 0.15, "h_bulk": 0.4, "h_solid": 0.2, "grading": 0.5},
    "coarse": {"h_interface": 0.08, "h_bulk": 0.25, "h_solid": 0.12, "grading": 0.5},
    "paper": {"h_interface": 0.06, "h_bulk": 0.2, "h_solid": 0.1, "grading": 0.4},
}

#: config keys that change the mesh or the compiled forms (everything else is a value)
_STRUCTURAL = ("geometry", "mesh", "fluid", "material.law", "solver.order", "solver.ale_weight",
               "physics.layer.enabled", "physics.layer.where", "physics.layer.thickness",
               "physics.growth.enabled", "physics.stiffening.enabled",
               "physics.gravity.enabled", "physics.permeability.enabled")


def fsi_section(config: Mapping[str, Any]) -> dict[str, Any]:
    """The fsi section of ``config``: ``config["forward_model"]["fsi"]`` for a whole study
    config (top-level ``forward_model`` key), else ``config`` itself."""
    if "forward_model" in config:
        fm = config["forward_model"]
        if not isinstance(fm, Mapping) or not isinstance(fm.get("fsi", {}), Mapping):
            raise ConfigError("key 'forward_model.fsi' must be a mapping")
        return dict(fm.get("fsi") or {})
    return dict(config)


#: the candidate physics (:mod:`bayescalib.models.fsi.physics`) of the 3D model: all of
#: them, through the same forms as in 2D
PHYSICS_3D = tuple(CANDIDATES)


def finer_preset(dim: int, preset: str) -> str | None:
    """The next finer mesh preset of the ``dim``-dimensional model (the one with the
    largest interface element size below ``preset``'s), or None for the finest."""
    presets = MESH_PRESETS if int(dim) == 2 else MESH_PRESETS_3D
    h = presets[preset]["h_interface"]
    finer = [p for p in presets if presets[p]["h_interface"] < h]
    return max(finer, key=lambda p: presets[p]["h_interface"]) if finer else None


def dim3_problem(cfg: Mapping[str, Any]) -> str:
    """What a validated fsi config asks of the 3D model that it does not have, or ``""``.

    The 3D model (``geometry.dim: 3``): one half-ellipsoidal colony, a scanned one
    (:mod:`bayescalib.models.fsi.scan3d`) or a ridge across the width (no polyline
    shape, no subdomains), all the candidate physics (:data:`PHYSICS_3D`); its mesh
    presets are :data:`MESH_PRESETS_3D`. The ridge is a 3D shape only.
    """
    geo = cfg["geometry"]
    if int(geo["dim"]) != 3:
        return "geometry.shape: ridge is a 3D shape (geometry.dim: 3)" \
            if geo["shape"] == "ridge" else ""
    if geo["shape"] not in ("half_ellipse", "ridge", "scan"):
        return (f"geometry.shape: the 3D model has the half_ellipse, ridge and scan shapes "
                f"only, not '{geo['shape']}'")
    if geo["subdomains"]["enabled"]:
        return "geometry.subdomains: not available in the 3D model (geometry.dim: 3)"
    if cfg["mesh"]["preset"] not in MESH_PRESETS_3D:
        return (f"mesh.preset: no 3D preset '{cfg['mesh']['preset']}' "
                f"(3D presets: {', '.join(MESH_PRESETS_3D)})")
    return ""


def _get(cfg: Mapping[str, Any], dotted: str) -> Any:
    node: Any = cfg
    for part in dotted.split("."):
        node = node[part]
    return node


#: geometry keys only the 3D model reads (``geometry.dim`` 3); a 2D model's state key
#: leaves them out, so the states saved before they existed stay valid warm starts
GEOMETRY_3D_KEYS = ("dim", "channel_width", "depth", "centre_z", "side_walls", "height_field")


def _space_key(cfg: Mapping[str, Any], *, base: bool = False) -> str:
    """Key of what fixes the layout of a state vector (mesh and spaces): a state saved
    with one key is a valid initial guess for any model with the same key, whatever
    its material law or candidate physics. A permeable biofilm (candidate
    ``permeability``) adds the pore-pressure block; ``base=True`` gives the key of the
    same model without it (whose states are embedded for a warm start)."""
    data = {k: _get(cfg, k) for k in ("geometry", "mesh", "solver.order")}
    if cfg["geometry"]["dim"] == 2:  # a 2D state's key as before the 3D model's keys
        data["geometry"] = {k: v for k, v in data["geometry"].items()
                            if k not in GEOMETRY_3D_KEYS}
    if not base and cfg["physics"]["permeability"]["enabled"]:
        data["pore_pressure"] = True
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def _structural_key(cfg: Mapping[str, Any]) -> str:
    data = {k: _get(cfg, k) for k in _STRUCTURAL}
    data["springs"] = springs_active(cfg["physics"])  # the base clamp or springs
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def newton_per_step(history) -> str:
    """Newton iterations per load step, as text: "load:iterations" in the order solved
    (a failed step, later halved, as "load:failed"), e.g. "0.25:4 0.5:3 1:3"."""
    steps: list[list] = []
    for load, it, _size, _fresh in history:
        key = f"{load:.4g}"
        if steps and steps[-1][0] == key:
            steps[-1][1] = "failed" if it < 0 else max(it, steps[-1][1]) \
                if steps[-1][1] != "failed" else it
        else:
            steps.append([key, "failed" if it < 0 else it])
    return " ".join(f"{k}:{v}" for k, v in steps)


class FSIModel:
    """Steady FSI forward model of the biofilm flow cell.

    Parameters
    ----------
    config
        The fsi config section (validated here with :func:`bayescalib.config.validate`,
        which fills defaults; a whole study config with ``forward_model.fsi`` also works).

    Examples
    --------
    >>> model = FSIModel({"mesh": {"preset": "coarse"}})          # doctest: +SKIP
    >>> res = model.solve({"material.E": 250.0, "material.nu": 0.2})  # doctest: +SKIP
    >>> res.status, res.max_displacement                              # doctest: +SKIP
    """

    def __init__(self, config: Mapping[str, Any] | None = None):
        self.config = validate(fsi_section(config or {}), "fsi")
        msg = physics_problem(self.config["physics"]) or dim3_problem(self.config)
        if msg:
            raise ConfigError(msg)
        self.physics: SolidPhysics | None = None
        self._key: str | None = None
        self._space: str | None = None
        self._base_space: str | None = None
        self.geometry: BiofilmMesh | None = None
        self.solver: MonolithicSolver | None = None
        self._last_state: np.ndarray | None = None
        self._last_params: dict[str, float] = {}
        self.build_time = 0.0

    # ------------------------------------------------------------------ building
    def _build(self, cfg: Mapping[str, Any]) -> None:
        import ngsolve as ng

        key = _structural_key(cfg)
        if key == self._key:
            return
        t0 = time.perf_counter()
        ng.SetNumThreads(1)
        dim = int(cfg["geometry"]["dim"])
        mesh_cfg = dict(cfg["mesh"])
        presets = MESH_PRESETS if dim == 2 else MESH_PRESETS_3D
        for name, value in presets[mesh_cfg["preset"]].items():
            if mesh_cfg.get(name) is None:
                mesh_cfg[name] = value
        H = float(cfg["geometry"]["channel_height"])
        law = cfg["material"]["law"]
        if dim == 3:
            from bayescalib.models.fsi.geometry3d import build_mesh_3d

            geo = build_mesh_3d(cfg["geometry"], mesh_cfg)
            profile, clamp = _channel_3d(cfg["geometry"])
        else:
            geo = build_mesh(cfg["geometry"], mesh_cfg)

            def profile():
                # parabolic profile with unit volume rate (scaled by the rate in solve())
                return ng.CoefficientFunction((6.0 * ng.y * (H - ng.y) / H**3, 0.0))

            clamp = {
                "velocity_dirichlet": "inlet|floor|top|biofilm_floor",
                "displacement_dirichlet": "inlet|outlet|floor|top|biofilm_floor",
            }

        physics = SolidPhysics(cfg["physics"], geo.patch_height, dim=dim)
        if physics.springs:
            clamp = _sliding_base(clamp, dim)
        problem = FSIProblem(
            mesh=geo.mesh,
            fluid="fluid",
            solids={name: law for name in geo.solid_regions},
            inflow="inlet",
            inflow_profile=profile,
            rho_fluid=float(cfg["fluid"]["density"]) * KG_PER_M3,
            mu_fluid=float(cfg["fluid"]["viscosity"]) * PA_S,
            interface="interface",
            ale_weight=float(cfg["solver"]["ale_weight"]),
            length_scale=float(mesh_cfg["h_interface"]),
            order=int(cfg["solver"]["order"]),
            physics=physics,
            **clamp,
        )
        self.solver = MonolithicSolver(problem)
        self.physics = physics
        self._unit_inflow = self.solver._inflow_val.copy()
        # the odd part of the skewed inflow (candidate inflow_skew): the profile times
        # (2y/H - 1), less the multiple of the profile that its discrete volume rate
        # is (the inlet mesh is not symmetric in y: 1e-3 of the rate on the 3D
        # very_coarse mesh, 1e-17 in 2D), so that a skew keeps the rate to round-off
        skew = self.solver.inflow_values(profile() * (2.0 * ng.y / H - 1.0))
        self._unit_skew = skew - (self.solver.inflow_rate(skew)
                                  / self.solver.inflow_rate(self._unit_inflow)) * self._unit_inflow
        self.geometry = geo
        self._key = key
        self._space = _space_key(cfg)
        self._base_space = _space_key(cfg, base=True)
        self._last_state = None
        self.build_time = time.perf_counter() - t0

    def _materials(self, cfg: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
        """(E, nu) per solid region in user units (Pa, -)."""
        assert self.geometry is not None
        mat = cfg["material"]
        if self.geometry.solid_regions == ["biofilm"]:
            return {"biofilm": (float(mat["E"]), float(mat["nu"]))}
        return {n: (float(mat["subdomains"][n]["E"]), float(mat["subdomains"][n]["nu"]))
                for n in SOLID_SUBDOMAINS}

    def _parameters(self, cfg: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, float]:
        assert self.geometry is not None
        out: dict[str, float] = {}
        if self.geometry.solid_regions == ["biofilm"]:
            out["material.E"] = float(cfg["material"]["E"])
            out["material.nu"] = float(cfg["material"]["nu"])
        else:
            for n in SOLID_SUBDOMAINS:
                out[f"material.subdomains.{n}.E"] = float(cfg["material"]["subdomains"][n]["E"])
                out[f"material.subdomains.{n}.nu"] = float(cfg["material"]["subdomains"][n]["nu"])
        out["inflow.rate"] = float(cfg["inflow"]["rate"])
        out.update(physics_parameters(cfg["physics"]))
        for k, v in overrides.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                out[k] = float(v)
        return out

    def resolved_config(self, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The config with dotted ``overrides`` applied and validated (raises ConfigError)."""
        cfg = copy.deepcopy(self.config)
        for k, v in (overrides or {}).items():
            set_dotted(cfg, k, v)
        cfg = validate(cfg, "fsi", where="overrides" if overrides else "")
        msg = physics_problem(cfg["physics"]) or dim3_problem(cfg)
        if msg:
            raise ConfigError(msg)
        return cfg

    # ------------------------------------------------------------------ states
    def save_state(self, path: str | Path) -> None:
        """Save the last solved state (a converged solution) for a later warm start (``.npz``)."""
        if self._last_state is None:
            raise ValueError("no solved state to save: call solve() first")
        with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, state=self._last_state, key=np.array(self._space),
                     parameters=np.array(json.dumps(self._last_params)))

    def _load_state(self, path: str | Path) -> np.ndarray:
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as data:
                state = np.array(data["state"], dtype=float)
                key = str(data["key"])
        except FileNotFoundError:
            raise ValueError(f"warm-start file '{path}' does not exist") from None
        except (OSError, KeyError, ValueError) as exc:
            raise ValueError(f"warm-start file '{path}' is not a saved FSI state: {exc}") from None
        assert self.solver is not None
        if key == self._base_space and key != self._space:
            embedded = self._embed(state)
            if embedded is not None:
                return embedded
        if key != self._space or state.shape[0] != self.solver.ndof:
            raise ValueError(
                f"warm-start file '{path}' was saved for another geometry/mesh/order "
                f"({state.shape[0]} unknowns, this model has {self.solver.ndof})"
            )
        return state

    def _embed(self, state: np.ndarray) -> np.ndarray | None:
        """A state of the same model without the pore pressure (an impermeable
        biofilm) as a state of this permeable one: the pore-pressure block, the last
        one, starts at zero. ``None`` when the sizes do not fit."""
        assert self.solver is not None
        s = self.solver
        if s.i_pore is None:
            return None
        start, stop = s._ranges[s.i_pore]
        if stop != s.ndof or state.shape[0] != start:
            return None
        return np.concatenate([state, np.zeros(stop - start)])

    def forget_solves(self) -> None:
        """Forget everything earlier solves left behind, keeping only what was built
        (mesh, spaces, compiled forms): the last state (``warm_start="last"``), the kept
        LU factorization and the state vector (back to rest). The next solve then
        computes bit for bit what it computes in a new model of the same config: it
        starts from rest or from its warm start, with a fresh factorization (a kept one
        would make its Newton iterates, and so its result, differ at the solver's
        tolerance and depend on which point was solved before). Used when one model
        solves many design points (:func:`bayescalib.models.forward.solve_points`)."""
        self._last_state = None
        self._last_params = {}
        if self.solver is not None:
            self.solver.factorization = None
            self.solver.reset()

    @property
    def last_state(self) -> np.ndarray | None:
        """Copy of the state vector of the last solve (``None`` before the first solve)."""
        return None if self._last_state is None else self._last_state.copy()

    # ------------------------------------------------------------------ solving
    def solve(
        self,
        overrides: Mapping[str, Any] | None = None,
        *,
        warm_start: str | Path | np.ndarray | None = None,
        time_limit: float | None = None,
        start_load: float | None = None,
    ) -> SolveResult:
        """Solve the steady FSI problem.

        Parameters
        ----------
        overrides
            Dotted config keys -> values, e.g. ``{"material.E": 250.0, "inflow.rate": 90.0,
            "material.subdomains.middle.E": 200.0}`` (user units). Changing geometry, mesh,
            fluid or law keys rebuilds the mesh.
        warm_start
            A state file from :meth:`save_state`, a state vector, or ``"last"`` for the
            last state of this model; used as the initial guess at full load (the solve
            falls back to continuation from rest if Newton fails from it).
        time_limit
            Wall-clock limit in s (default ``solver.time_limit_s``).
        start_load
            Inflow rate at which the warm-start state is a solution, as a fraction of
            this solve's rate (default 1: the same rate); the load continuation goes from
            there to 1, up or down. Used for a series of loadings
            (:meth:`solve_loadings`).

        Returns
        -------
        SolveResult
            Never raises for solver failures (non-convergence, NaN, inverted elements,
            nu >= 0.5, time limit): those give ``status == "failed"`` with a reason.

        Raises
        ------
        ConfigError
            Unknown override keys or out-of-range values.
        ValueError
            An unusable warm-start file.
        """
        t_start = time.perf_counter()
        overrides = dict(overrides or {})
        cfg = self.resolved_config(overrides)
        build_before = self._key
        self._build(cfg)
        built = build_before != self._key
        solver = self.solver
        geo = self.geometry
        assert solver is not None and geo is not None
        params = self._parameters(cfg, overrides)
        materials = self._materials(cfg)
        scfg = cfg["solver"]
        controls = SolverControls.from_config(scfg, time_limit=time_limit)
        initial = None
        if warm_start is not None:
            if isinstance(warm_start, np.ndarray):
                initial = np.asarray(warm_start, dtype=float)
                if initial.ndim == 1 and initial.shape[0] != solver.ndof:
                    embedded = self._embed(initial)  # a state of the impermeable model
                    initial = initial if embedded is None else embedded
                if initial.shape != (solver.ndof,):
                    raise ValueError(f"warm-start state has shape {initial.shape}, expected ({solver.ndof},)")
            elif isinstance(warm_start, str) and warm_start == "last":
                initial = self._last_state
            else:
                initial = self._load_state(warm_start)
            start = 1.0 if start_load is None else float(start_load)
            start_load = start if initial is not None else 0.0
        else:
            start_load = 0.0

        reason = ""  # non-finite values never get here: resolved_config rejects them
        rate = float(cfg["inflow"]["rate"])
        for _, nu in materials.values():
            reason = reason or poisson_problem(nu)
        reason = reason or unsupported_combination(cfg["physics"])
        base_stats: dict[str, Any] = {
            "ndof": solver.ndof,
            "nfree": solver.nfree,
            "n_interface_nodes": len(geo.interface_vertices),
            "n_elements": int(geo.mesh.ne),
            "h_interface": float(solver.problem.length_scale),
            "law": cfg["material"]["law"],
            "warm_start": int(initial is not None),
            "build_time": float(self.build_time if built else 0.0),
            "units": "mm, Pa, mm^2/s, s",
        }
        if solver.dim == 3:
            base_stats.update(dim=3, n_interface_triangles=len(geo.segments),
                              units="mm, Pa, mm^3/s, s")
        if reason:
            solver.reset()
            return self._result("failed", reason, params, 0.0, 0, 0, t_start, base_stats)

        solver.set_materials({n: (E * PA, nu) for n, (E, nu) in materials.items()})
        assert self.physics is not None
        self.physics.set_values(cfg["physics"], PA,
                                viscosity=float(cfg["fluid"]["viscosity"]) * PA_S)
        unit = self._unit_inflow
        if cfg["physics"]["inflow_skew"]["enabled"]:
            unit = unit + float(cfg["physics"]["inflow_skew"]["phi"]) * self._unit_skew
        solver._inflow_val = unit * rate
        if initial is None:
            solver.reset()
        keep = bool(scfg["keep_factorization"]) and initial is not None and not built
        if initial is not None:
            controls.chord_threshold = float(scfg["chord_threshold_warm"])
        try:
            outcome = solver.solve(controls, initial=initial, start_load=start_load,
                                   keep_factorization=keep)
        except Exception as exc:  # noqa: BLE001 - a solver failure is data, never a crash of the study
            solver.reset()
            return self._result("failed", f"solver error: {type(exc).__name__}: {exc}", params,
                                0.0, 0, 0, t_start, base_stats)
        base_stats.update({
            "factorizations": outcome.factorizations,
            "min_det_F": solver.min_det_F(),
            "max_interface_velocity": self._max_interface_velocity(),
            **{k: float(v) for k, v in outcome.timings.items()},
        })
        status = "ok" if outcome.ok else "failed"
        if outcome.ok:
            self._last_state = solver.get_state()
            self._last_params = params
        res = self._result(status, outcome.reason, params, outcome.load_fraction,
                           outcome.newton_iterations, outcome.load_steps, t_start, base_stats)
        return res

    def solve_loadings(
        self,
        overrides: Mapping[str, Any] | None,
        factors: list[float],
        *,
        warm_start: str | Path | np.ndarray | None = None,
        time_limit: float | None = None,
    ) -> list[SolveResult]:
        """Solve a series of loadings ``factors * inflow.rate`` by continuation.

        Without a warm start the loadings are solved in increasing order, each starting
        from the previous converged state (the first from rest). With a warm start (a
        state at the nominal rate, factor 1) a zero loading is solved first, from rest
        (it needs no other loading, and so never waits for a slow one to use up the
        time limit of the series); then the factors <= 1 are solved downwards from the
        warm state and those > 1 upwards from it, the first of them with the
        factorization this model kept before the series, as if the zero loading had
        not been solved. After a failed loading the next one continues from the last
        converged state.

        Parameters
        ----------
        overrides
            As in :meth:`solve` (the nominal ``inflow.rate`` included).
        factors
            Loading factors (>= 0) relative to the nominal inflow rate.
        warm_start
            As in :meth:`solve`; a state at the nominal rate.
        time_limit
            Wall-clock limit in s for the whole series (default ``solver.time_limit_s``).

        Returns
        -------
        list of SolveResult
            One per factor, in the order of ``factors``; ``inflow.rate`` in each
            result's parameters is the loading's rate.
        """
        overrides = dict(overrides or {})
        cfg = self.resolved_config(overrides)
        nominal = float(cfg["inflow"]["rate"])
        limit = float(time_limit if time_limit is not None else cfg["solver"]["time_limit_s"])
        t_end = time.perf_counter() + limit
        f = [float(x) for x in factors]
        if any(x < 0 or not np.isfinite(x) for x in f):
            raise ConfigError(f"loading factors must be finite and >= 0, got {factors}")
        zeros = [k for k in range(len(f)) if f[k] == 0.0]
        if warm_start is None:
            chains = [sorted(range(len(f)), key=lambda k: f[k])]
        else:
            chains = [zeros,
                      sorted((k for k in range(len(f)) if 0.0 < f[k] <= 1.0), key=lambda k: -f[k]),
                      sorted((k for k in range(len(f)) if f[k] > 1.0), key=lambda k: f[k])]
        kept = None if self.solver is None else self.solver.factorization  # before the series
        results: dict[int, SolveResult] = {}
        for i, chain in enumerate(chains):
            if warm_start is not None and i == 1 and self.solver is not None:
                self.solver.factorization = kept  # not the zero loading's
            state: Any = warm_start
            state_factor = 1.0 if warm_start is not None else None
            for k in chain:
                ov = {**overrides, "inflow.rate": f[k] * nominal}
                remaining = max(t_end - time.perf_counter(), 1e-3)
                if state is None or f[k] == 0.0 or state_factor is None:
                    res = self.solve(ov, time_limit=remaining)
                else:
                    res = self.solve(ov, warm_start=state, time_limit=remaining,
                                     start_load=state_factor / f[k])
                if res.ok:
                    state, state_factor = "last", f[k]
                results[k] = res
        return [results[k] for k in range(len(f))]

    def _interface_displacement(self) -> np.ndarray:
        """(n, dim) displacement (mm) of the interface vertices in the current state."""
        assert self.solver is not None and self.geometry is not None
        s = self.solver
        return _vertex_values(s.block(s.i_d), self.geometry.interface_vertices, s.dim)

    def _max_interface_velocity(self) -> float:
        assert self.solver is not None and self.geometry is not None
        ub = _vertex_values(self.solver.block(0), self.geometry.interface_vertices,
                            self.solver.dim)
        return float(np.max(_norms(ub)))

    def _result(self, status, reason, params, load_fraction, iters, steps, t_start, stats) -> SolveResult:
        assert self.geometry is not None
        ref = self.geometry.interface_reference.copy()
        disp = self._interface_displacement()
        cur = ref + disp
        stats = dict(stats)
        stats["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        if self.solver is not None and getattr(self.solver, "history", None) is not None:
            stats["newton_per_step"] = newton_per_step(self.solver.history)
            if self.solver.failures:
                stats["failed_steps"] = "; ".join(self.solver.failures)[-1000:]
        return SolveResult(
            status=status,
            reason=reason,
            parameters=params,
            load_fraction=float(load_fraction),
            newton_iterations=int(iters),
            load_steps=int(steps),
            wall_time=time.perf_counter() - t_start,
            interface_reference=ref,
            interface_current=cur,
            segments=self.geometry.segments.copy(),
            max_displacement=float(np.max(_norms(disp))),
            stats=stats,
        )

    def write_vtu(self, path: str | Path) -> None:
        """Write velocity, pressure and displacement of the current state on the deformed mesh."""
        from bayescalib.models.fsi.vtu import write_fields_vtu

        assert self.solver is not None
        write_fields_vtu(path, self.solver)



def _vertex_values(block: np.ndarray, vertices: np.ndarray, dim: int) -> np.ndarray:
    """Values at mesh vertices of a vector P``k`` field from its state block.

    Parameters
    ----------
    block : ndarray, shape (dim * N,)
        The field's entries of the state vector: NGSolve's ``VectorH1`` holds ``dim``
        component blocks of ``N`` DOFs each, and the first DOFs of a block are the
        vertex values (hierarchical higher-order basis).
    vertices : ndarray, shape (n,)
        Mesh vertex numbers.
    dim : int
        Space dimension.

    Returns
    -------
    ndarray, shape (n, dim)
    """
    nd = block.shape[0] // dim
    return np.column_stack([block[k * nd + vertices] for k in range(dim)])


def _norms(v: np.ndarray) -> np.ndarray:
    """Euclidean norms of the rows of ``v`` (shape (n, 2) or (n, 3)); in 2D
    ``np.hypot``, as the 2D model has always computed them (bit for bit)."""
    if v.shape[1] == 2:
        return np.hypot(v[:, 0], v[:, 1])
    return np.linalg.norm(v, axis=1)


def _sliding_base(clamp: Mapping[str, Any], dim: int) -> dict[str, Any]:
    """The Dirichlet keyword arguments of :class:`FSIProblem` with the base on springs.

    Imperfect attachment (candidate ``attachment``): the base and the ALE mesh on the
    floor slide tangentially, in x (in 3D x and z): in those components
    ``biofilm_floor`` leaves the velocity's Dirichlet boundaries (the solid's ``u = 0``
    rows hold its velocity), ``floor`` and ``biofilm_floor`` the displacement's; the
    base gets the springs (``spring_boundary``). The normal (y) components keep the
    clamp's: no lift-off, no penetration.
    """
    def without(regex: str, names: tuple[str, ...]) -> str:
        return "|".join(n for n in regex.split("|") if n not in names)

    u = clamp.get("velocity_dirichlet_xy") or (clamp["velocity_dirichlet"],) * dim
    d = clamp.get("displacement_dirichlet_xy") or (clamp["displacement_dirichlet"],) * dim
    return {**clamp,
            "velocity_dirichlet_xy": tuple(
                r if c == 1 else without(r, ("biofilm_floor",)) for c, r in enumerate(u)),
            "displacement_dirichlet_xy": tuple(
                r if c == 1 else without(r, ("floor", "biofilm_floor")) for c, r in enumerate(d)),
            "spring_boundary": "biofilm_floor"}


def _channel_3d(geometry: Mapping[str, Any]) -> tuple[Any, dict[str, Any]]:
    """Inflow profile (unit volume rate) and Dirichlet boundaries of the 3D channel.

    No-slip side walls (``side_walls: no_slip``): the developed rectangular-duct
    profile (:func:`bayescalib.models.fsi.duct.duct_velocity` divided by its rate), so
    that the flow arrives fully developed as the 2D model's parabola does; no-slip on
    ``inlet|floor|top|side|biofilm_floor``, the ALE displacement zero on the channel
    walls. Slip side walls (symmetry planes, ``slip``): ``u_z = 0`` and ``d_z = 0`` on
    ``side`` (the other components free: the mesh, and a colony touching the wall,
    slide along it), and the 2D parabola ``6 Q y (H - y) / (H^3 W)``, uniform in z.

    Returns
    -------
    profile : callable
        ``profile()`` gives the (3,) NGSolve coefficient function of the inflow velocity
        at unit volume rate (mm/s per mm^3/s).
    clamp : dict
        The Dirichlet keyword arguments of :class:`FSIProblem`.
    """
    import ngsolve as ng

    from bayescalib.models.fsi.duct import duct_flow_rate, duct_velocity

    H = float(geometry["channel_height"])
    W = float(geometry["channel_width"])
    walls = "inlet|floor|top|biofilm_floor"
    if geometry["side_walls"] == "slip":
        def profile():
            return ng.CoefficientFunction((6.0 * ng.y * (H - ng.y) / (H**3 * W), 0.0, 0.0))

        return profile, {
            "velocity_dirichlet_xy": (walls, walls, walls + "|side"),
            "displacement_dirichlet_xy": (walls + "|outlet", walls + "|outlet",
                                          walls + "|outlet|side"),
            "velocity_dirichlet": walls + "|side",
            "displacement_dirichlet": walls + "|outlet|side",
        }
    rate = duct_flow_rate(H, W)

    def profile():
        return ng.CoefficientFunction((duct_velocity(ng.y, ng.z, H, W, lib=ng) / rate, 0.0, 0.0))

    return profile, {"velocity_dirichlet": walls + "|side",
                     "displacement_dirichlet": walls + "|outlet|side"}
