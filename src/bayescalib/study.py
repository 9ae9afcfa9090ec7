"""A calibration study: its validated configuration, its output layout, and
the config *sections* each pipeline stage depends on.

The Snakemake workflow passes every rule only the sections it depends on, as
plain Python values, so that Snakemake's parameter trigger reruns exactly what
changed: a GP setting never reruns a forward solve, and adding Sobol points
solves only the new ones (the design has the prefix property, so the values of
the first ``n`` points do not change when ``n`` grows; the solve of point ``i``
depends only on the forward-model section and on the values of point ``i``).

This module is imported when the Snakefile is parsed, so it imports only the
configuration machinery; the Sobol design (SciPy) is computed lazily, when the
DAG first asks for a point.
"""

from __future__ import annotations

import copy
import itertools
import math
import os
from collections.abc import Mapping, Sequence
from functools import cached_property
from pathlib import Path
from typing import Any

from bayescalib.config import ConfigError, round_smc, sorted_keys, validate

__all__ = ["ConfigError", "Study", "StudyBusyError", "hold_run_lock"]

#: most measurement points a ``measure.euclidean.points`` file may hold (each is a line
#: intersected with every solve's interface; the default rule places 10)
MAX_MEASUREMENT_POINTS = 10_000
#: an observed 3D colony whose footprint's centre lies farther than this share of the
#: model's footprint from it is misplaced (its base is attached: the flow barely moves it)
FOOTPRINT_SHIFT = 0.1


def _entry_at(cfg: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    """The observation file entry a key such as ``observations.files[2]`` names."""
    obs = cfg["observations"]
    if key == "observations.reference":
        return obs["reference"]
    return obs["files"][int(key[key.index("[") + 1 : key.index("]")])]


class StudyBusyError(RuntimeError):
    """Another process is running the same study (same results folder)."""


#: run locks held by this process (kept open: a lock lasts as long as its file is open)
_HELD_LOCKS: dict[str, Any] = {}


def run_lock_holder(root: str | Path) -> str | None:
    """Who holds the run lock of the study under ``root`` (its text, e.g. "snakemake
    pid 123"), or None when no live process holds it. Takes nothing: a free lock is
    released again at once."""
    import fcntl

    path = Path(root) / ".run.lock"
    if str(path.resolve()) in _HELD_LOCKS or not path.is_file():
        return None
    with open(path) as fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return fh.read().strip() or "another process"
        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
    return None


JOBS_LOCK = ".jobs.lock"


def hold_job_lock(root: str | Path) -> None:
    """Mark this process as a running job of the study under ``root`` for the rest of
    its life: a shared kernel lock on ``<root>/.jobs.lock`` (released by the kernel
    however the job ends). A Snakemake run that was killed leaves its jobs running as
    orphans; a new run sees their locks and waits for them instead of running beside
    them (:func:`job_lock_holders`)."""
    import fcntl

    path = Path(root) / JOBS_LOCK
    key = "jobs:" + str(path.resolve())
    if key in _HELD_LOCKS:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    fh = open(path, "a")  # noqa: SIM115 - held open for the life of the process
    fcntl.flock(fh.fileno(), fcntl.LOCK_SH)
    _HELD_LOCKS[key] = fh


def job_lock_holders(root: str | Path) -> list[int] | None:
    """PIDs of processes holding the job lock of the study under ``root`` (an empty
    list when they cannot be named), or None when no job of the study is running."""
    import fcntl
    import os

    path = Path(root) / JOBS_LOCK
    if not path.is_file():
        return None
    with open(path) as fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            pass
        else:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
            return None
        ino = os.fstat(fh.fileno()).st_ino
    pids: list[int] = []
    try:  # Linux: /proc/locks names the holders ("... <pid> <maj>:<min>:<inode> ...")
        for line in Path("/proc/locks").read_text().splitlines():
            parts = line.split()
            if len(parts) > 5 and parts[1] == "FLOCK" and parts[5].endswith(f":{ino}"):
                pids.append(int(parts[4]))
    except (OSError, ValueError):
        pass
    return sorted(set(pids) - {os.getpid()})


#: command-line options of a Snakemake call that only looks (never runs a job)
_LOOK_ONLY = {"-n", "--dry-run", "--dryrun", "--report", "--lint", "--list", "-l",
              "--list-rules", "--summary", "-S", "--detailed-summary", "-D", "--dag",
              "--rulegraph", "--filegraph", "--list-changes", "--lc", "--list-input-changes",
              "--li", "--list-params-changes", "--lp", "--list-code-changes", "--lt",
              "--list-untracked", "--lu"}


def runs_jobs(argv: Sequence[str]) -> bool:
    """Whether a Snakemake command line (``sys.argv``) may run jobs or unlock (False
    for a dry run, a report, a lint, a listing)."""
    for a in argv[1:]:
        if a.split("=", 1)[0] in _LOOK_ONLY:
            return False
        if a.startswith("-") and not a.startswith("--") and len(a) > 2 and "n" in a[1:]:
            return False  # combined short flags such as -np
    return True


def hold_run_lock(root: str | Path, name: str) -> Path:
    """Take the run lock of the study whose outputs are under ``root``, for the life
    of this process.

    Snakemake's own lock refuses a second run that would write the same files, but
    any Snakemake run that ends in the working directory deletes the locks of all
    (``.snakemake/locks`` is removed as a whole), so with two studies running side by
    side the first to finish unlocks the other. This lock is a kernel lock
    (``flock``) on ``<root>/.run.lock``: the kernel releases it when the process
    ends, however it ends (no stale lock after a kill, nothing to unlock).

    Raises
    ------
    StudyBusyError
        If another process holds it.
    """
    import fcntl
    import os

    path = Path(root) / ".run.lock"
    key = str(path.resolve())
    if key in _HELD_LOCKS:
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    fh = open(path, "a+")  # noqa: SIM115 - held open for the life of the process
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.seek(0)
        holder = fh.read().strip()
        fh.close()
        raise StudyBusyError(
            f"study '{name}' is already being run in this directory "
            f"({holder or 'another process'}; lock {path}). Wait for that run to end (or "
            "stop it with Ctrl-C), then run its command again to resume; do not --unlock "
            "or --rerun-incomplete while it runs. Another study can run at the same time."
        ) from None
    fh.seek(0)
    fh.truncate()
    fh.write(f"snakemake pid {os.getpid()}\n")
    fh.flush()
    _HELD_LOCKS[key] = fh
    return path


class Study:
    """Validated study configuration with derived paths and rule sections.

    Parameters
    ----------
    config
        The raw study configuration (e.g. Snakemake's ``config``).
    where
        Name of the configuration's source for error messages.
    """

    def __init__(self, config: Mapping[str, Any], *, where: str = "config"):
        cfg = validate(config, "study", where=where)
        #: plain-words notes on settings that were ignored (printed when the workflow starts)
        self.notes: list[str] = self._validate_consistency(cfg, where)
        self.config: dict[str, Any] = sorted_keys(cfg)

    # ------------------------------------------------------------------ checks
    @staticmethod
    def _validate_consistency(cfg: dict[str, Any], where: str) -> list[str]:
        """Check what the schema cannot; resolve ``auto`` settings; return notes."""
        from bayescalib.inference.parameters import (
            ParameterError,
            ParameterSpace,
            parameter_target,
        )

        notes: list[str] = []
        try:
            ParameterSpace.from_config(cfg["parameters"])
        except ParameterError as exc:
            raise ConfigError(f"{where}: parameters: {exc}") from None
        for p in cfg["parameters"]:  # from here on every parameter has its target
            p["target"] = parameter_target(p)
        fm = cfg["forward_model"]
        kind = fm["type"]
        if kind == "python" and "function" not in fm["python"]:
            raise ConfigError(
                f"{where}: forward_model.python.function is required when forward_model.type is python"
            )
        if kind == "command":
            for key in ("template", "command"):
                if key not in fm["command"]:
                    raise ConfigError(
                        f"{where}: forward_model.command.{key} is required when "
                        "forward_model.type is command"
                    )
            if not Path(fm["command"]["template"]).is_file():
                raise ConfigError(
                    f"{where}: forward_model.command.template: file "
                    f"'{fm['command']['template']}' does not exist"
                )
        Study._validate_model(fm, where)
        if fm["warm_start"] == "auto":
            fm["warm_start"] = "prior_centre" if kind == "fsi" else "none"
        elif fm["warm_start"] != "none" and kind != "fsi":
            notes.append(f"{where}: forward_model.warm_start: '{fm['warm_start']}' is a setting of "
                         f"the fsi model; ignored for the {kind} model")
            fm["warm_start"] = "none"
        rk = cfg["measure"]["rkhs"]
        if rk["residual"] == "auto":  # the distance vector the output emulator learns
            rk["residual"] = "field" if cfg["surrogate"]["target"] == "outputs" else "scalar"
        conv = cfg["convergence"]
        if conv["enabled"] and cfg["design"]["strategy"] != "fixed":
            raise ConfigError(
                f"{where}: convergence.enabled needs design.strategy: fixed (the GP convergence "
                "study refits on prefixes of a Sobol design and tests on held-out Sobol points)"
            )
        if conv["enabled"] and cfg["surrogate"]["target"] != "loglik":
            raise ConfigError(
                f"{where}: convergence.enabled needs surrogate.target: loglik (the GP "
                "convergence study refits the study's GP of the log-likelihood on prefixes of "
                "its design; the output emulator has no such study)"
            )
        act = cfg["design"]["active"]
        if cfg["design"]["strategy"] == "active" and act["n_initial"] > act["max_solves"]:
            raise ConfigError(
                f"{where}: design.active.n_initial ({act['n_initial']}) exceeds "
                f"design.active.max_solves ({act['max_solves']})"
            )
        if conv["enabled"] and max(conv["n_train"]) > cfg["design"]["n_train"]:
            raise ConfigError(
                f"{where}: convergence.n_train: largest value {max(conv['n_train'])} exceeds "
                f"design.n_train = {cfg['design']['n_train']}"
            )
        Study._validate_cost(cfg, where)
        names = [p["name"] for p in cfg["parameters"]]
        obs = cfg["observations"]
        if obs["source"] == "synthetic":
            missing = [p["name"] for p in cfg["parameters"] if p.get("ground_truth") is None]
            if missing:
                raise ConfigError(
                    f"{where}: observations.source is synthetic, so every parameter needs a "
                    f"ground_truth; missing for: {', '.join(missing)}"
                )
        if len(set(names)) != len(names):
            raise ConfigError(f"{where}: parameters: duplicate parameter names in {names}")
        try:
            from bayescalib.inference.likelihood import sigma_n2_from_config

            sigma_n2_from_config(cfg["likelihood"])
        except ValueError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        except OverflowError:  # sigma_n ** 2 beyond a float (e.g. 1e300)
            raise ConfigError(
                f"{where}: likelihood.sigma_n = {cfg['likelihood'].get('sigma_n')!r}: its "
                "square, the noise variance sigma_n2 (mm^2), overflows a float; sigma_n is "
                "the noise sd in mm") from None
        if obs.get("misregistration") and Study.model_dim(cfg) == 3:
            raise ConfigError(
                f"{where}: observations.misregistration is a 2D misplacement (shift_x, "
                "shift_y, rotation in the x-y plane, scale); the 3D model "
                "(forward_model.fsi.geometry.dim: 3) has none: leave it out")
        Study._validate_loadings(cfg, where)
        if cfg["forward_model"]["type"] == "fsi":
            from bayescalib.models.units import validate_fsi_units

            # before the boxes: the unit is the cause
            validate_fsi_units(cfg["parameters"], where, dim=Study.model_dim(cfg) or 2)
            notes += Study._resolve_geometry(cfg, where)
            notes += Study._validate_channel_ends(cfg, where)
            Study._validate_scan_not_observed(cfg, where)
            Study._validate_boxes(cfg, where)
        Study._validate_hidden(cfg, where)
        observed, read = Study._validate_observation_files(cfg, where)
        notes += Study._pixel_size_notes(cfg, where)
        Study._validate_measure_points(cfg, where)
        notes += Study._validate_colony_choice(cfg, where, observed, read)
        Study._validate_registration(cfg, where, observed, read)
        if "rkhs" in cfg["measures"]:  # after the unit check, whose words are the clearer
            for key, iface in observed.items():
                if key != "observations.reference":
                    Study._validate_rkhs_cost(cfg, where, key,
                                              Path(_entry_at(cfg, key)["path"]), iface)
        Study._validate_diagnose(cfg, where)
        return notes

    @staticmethod
    def _validate_model(fm: dict[str, Any], where: str) -> None:
        """What a solve would find wrong with a python or command model before it
        computes anything: the python callable importable, callable and taking its
        options (the module is imported now, as a solve imports it); the command's program
        found and its template parsed."""
        if fm["type"] not in ("python", "command"):
            return
        from bayescalib.models.forward import (  # not for the fsi model: parsing stays cheap
            CommandModel,
            ForwardModelError,
            load_callable,
            validate_call,
            validate_executable,
        )

        try:
            if fm["type"] == "python":
                validate_call(load_callable(fm["python"]["function"]),
                           fm["python"].get("options") or {})
            elif fm["type"] == "command":
                c = fm["command"]
                validate_executable(c["command"][0])
                # built, not run: the template parses and the names are valid (no folder made)
                CommandModel(c["template"], c["command"], input_name=c["input_name"],
                             output_name=c["output_name"], workdir="read.work", units=c["units"])
        except ForwardModelError as exc:
            raise ConfigError(f"{where}: {exc}") from None

    @staticmethod
    def _validate_cost(cfg: dict[str, Any], where: str) -> None:
        """The cost of the work, known before any job: the design's size, the estimated
        time of the GP fits and of one SMC tempering step, and the SMC's memory, each
        against its limit (:mod:`bayescalib.inference.cost`, ``smc.max_memory_gib``);
        a study above one is refused naming the key that makes it so."""
        from bayescalib.config import schema
        from bayescalib.inference import cost

        design, act, conv = cfg["design"], cfg["design"]["active"], cfg["convergence"]
        active = design["strategy"] == "active"
        sizes = [("design.active.max_solves", act["max_solves"])] if active else \
            [("design.n_train", design["n_train"])] \
            + ([("design.n_test", design["n_test"])] if conv["enabled"] else [])
        dg = cfg["diagnose"]
        if dg["enabled"]:
            sizes += [(f"diagnose.{k}", dg[k]) for k in ("n_train", "max_solves")
                      if dg[k] is not None]
        points = sum(int(v) for k, v in sizes if not k.startswith("diagnose"))
        worst = max(sizes, key=lambda kv: int(kv[1]))
        if points > cost.MAX_DESIGN_POINTS or int(worst[1]) > cost.MAX_DESIGN_POINTS:
            key, value = worst
            start = cost.gp_fit_seconds(int(value), starts=1, d=len(cfg["parameters"]))
            raise ConfigError(
                f"{where}: {key} = {value}: more design points (forward solves) than "
                f"{cost.MAX_DESIGN_POINTS:,} (bayescalib.inference.cost.MAX_DESIGN_POINTS): "
                f"a GP fit on {int(value):,} points would take about {cost.duration(start)} "
                "per optimizer start (its cost grows as n^3). A GP surrogate learns from a "
                "few hundred to a few thousand solves: use fewer")
        defaults = schema("inference")["definitions"]
        design_key, n_top = sizes[0]
        limit = cost.MAX_GP_HOURS * 3600.0
        gp = cost.study_gp_seconds(cfg)
        if gp.seconds > limit:
            one = cost.study_gp_seconds(cfg, restarts=1)
            if one.seconds > limit:
                raise ConfigError(
                    f"{where}: {design_key} = {n_top}: the GP fits would take about "
                    f"{cost.duration(one.seconds)} even with surrogate.restarts: 1 ({one.detail}"
                    + (f"; rounds of design.active.batch_size = {act['batch_size']}" if active
                       else "") + f"), above the limit of {cost.MAX_GP_HOURS:g} h "
                    "(bayescalib.inference.cost.MAX_GP_HOURS): use fewer design points"
                    + (", larger batches" if active else "")
                    + " or fewer candidate models (surrogate.kernel, output, frame, inputs)")
            fit = max(1, int(limit // one.seconds))
            raise ConfigError(
                f"{where}: surrogate.restarts = {cfg['surrogate']['restarts']}: the GP fits "
                f"would take about {cost.duration(gp.seconds)} ({gp.detail}), above the "
                f"limit of {cost.MAX_GP_HOURS:g} h (bayescalib.inference.cost.MAX_GP_HOURS): "
                "use a few (the schema's default is "
                f"{defaults['surrogate']['properties']['restarts']['default']}; the limit "
                f"allows at most {fit:,})")
        smc_cfg = cfg["smc"]
        n_particles, key = smc_cfg["n_particles"], "smc.n_particles"
        round_n = act["smc"].get("n_particles")  # optional: the rounds' own particles
        if active and round_n is not None and round_n > n_particles:
            n_particles, key = round_n, "design.active.smc.n_particles"
        need = n_particles * (6 * len(cfg["parameters"]) + int(n_top) + 10) * 8 / 2**30
        if need > smc_cfg["max_memory_gib"]:
            raise ConfigError(
                f"{where}: {key} = {n_particles} needs about {need:.3g} GiB "
                f"with {len(cfg['parameters'])} parameters and up to {n_top} training points "
                f"({design_key}), above smc.max_memory_gib = {smc_cfg['max_memory_gib']:g}: "
                "use fewer particles or raise the limit")
        step_limit = cost.MAX_SMC_STEP_MINUTES * 60.0
        for section, settings, est in cost.study_smc_steps(cfg):
            if est.seconds <= step_limit:
                continue
            own = act["smc"] if section != "smc" else settings
            # the setting furthest above the schema's default is named (inherited ones
            # by their own key)
            name = max(("n_rej", "n_particles"), key=lambda k: settings[k] / max(
                1, defaults["smc"]["properties"][k]["default"]))
            full = f"{section}.{name}" if name in own else f"smc.{name}"
            fit = max(1, int(settings[name] * step_limit / est.seconds))
            raise ConfigError(
                f"{where}: {full} = {settings[name]}: one tempering step of "
                + ("the active rounds' SMC" if section != "smc" else "SMC")
                + f" would take about {cost.duration(est.seconds)} ({est.detail}), above "
                f"the limit of {cost.MAX_SMC_STEP_MINUTES:g} min a step "
                f"(bayescalib.inference.cost.MAX_SMC_STEP_MINUTES): use fewer (the schema's "
                f"default is {defaults['smc']['properties'][name]['default']}; the limit "
                f"allows at most {fit:,})")

    @staticmethod
    def _resolve_geometry(cfg: dict[str, Any], where: str) -> list[str]:
        """``geometry.shape: scan``: read the colony from its recording now, check that
        it can be meshed, and fill ``geometry.outline`` with its interface, so every
        solve depends on the points (a changed scan reruns them) and none reads the
        file. Returns a note saying which colony was taken and how."""
        from bayescalib.geometry.outline import OutlineError, validate_colony
        from bayescalib.io.colony import read_colony
        from bayescalib.io.observations import ObservationError
        from bayescalib.models.fsi.model import MESH_PRESETS

        fsi = validate(cfg["forward_model"]["fsi"], "fsi")  # the section's values, defaults in
        geo = fsi["geometry"]
        key = f"{where}: forward_model.fsi.geometry"
        if geo["shape"] != "scan":
            if geo.get("scan"):
                raise ConfigError(f"{key}.scan is given but geometry.shape is "
                                  f"'{geo['shape']}': set shape: scan to model the scanned colony")
            return []
        if not geo.get("scan"):
            raise ConfigError(f"{key}.scan is required with shape: scan (the recording at zero "
                              "flow whose colony the model meshes)")
        if geo.get("outline"):
            raise ConfigError(f"{key}.outline is filled from geometry.scan with shape: scan; "
                              "leave it out")
        if int(geo["dim"]) == 3:
            return Study._resolve_scan_3d(cfg, fsi, where)
        if geo["scan"].get("spacing") is not None:
            raise ConfigError(f"{key}.scan.spacing applies to a 3D model's scan "
                              "(geometry.dim: 3); leave it out")
        if geo["scan"].get("component") is not None:
            raise ConfigError(f"{key}.scan.component applies to a 3D model's scan (a volume "
                              "or a surface); a 2D scan's colony is chosen by scan.colony")
        if isinstance(geo["scan"].get("pixel_size"), list) or len(geo["scan"].get("origin")
                                                                  or ()) > 2:
            raise ConfigError(f"{key}.scan: a 2D model's scan is an image or an outline: "
                              "pixel_size is one number and origin [x, y] (three of each are "
                              "an OCT volume's, for geometry.dim: 3)")
        if geo.get("height_field"):
            raise ConfigError(f"{key}.height_field is a 3D model's (geometry.dim: 3); "
                              "leave it out")
        try:
            colony = read_colony(geo["scan"], where=f"{key}.scan")
        except ObservationError as exc:
            raise ConfigError(f"{where}: {exc}" if not str(exc).startswith(where) else str(exc)) \
                from None
        mesh = {**MESH_PRESETS[fsi["mesh"]["preset"]],
                **{k: v for k, v in fsi["mesh"].items() if v is not None}}
        try:
            validate_colony(colony.interface, channel_length=float(geo["length"]),
                         channel_height=float(geo["channel_height"]),
                         min_gap=2.0 * float(mesh["h_interface"]), name=f"{key}.scan")
        except OutlineError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        cfg["forward_model"]["fsi"]["geometry"]["outline"] = [
            [round(float(x), 9), round(float(y), 9)] for x, y in colony.interface]
        i = colony.info
        return [(f"{key}.scan: the model's biofilm is the colony of '{i['source']}' "
                 f"({i['colony']}; x = {i['x_range_mm'][0]:.4g} to {i['x_range_mm'][1]:.4g} mm, "
                 f"{i['height_mm']:.4g} mm high, smoothed at {i['smoothing_mm'] * 1e3:.3g} um)")]

    @staticmethod
    def _resolve_scan_3d(cfg: dict[str, Any], fsi: dict[str, Any], where: str) -> list[str]:
        """``geometry.dim: 3`` with ``shape: scan``: read the colony's surface from
        ``geometry.scan``, take it as a height field, check it fits the channel with a
        gap of one interface element (the 3D presets are coarse: very_coarse's 0.15 mm
        is most of the default colony's 0.2 mm gap to the side walls;
        :func:`bayescalib.models.fsi.scan3d.scan_height_field`) and fill
        ``geometry.height_field`` with its grid, so every solve depends on the heights
        and none reads the file. Returns a note."""
        from bayescalib.models.fsi.model import MESH_PRESETS_3D
        from bayescalib.models.fsi.scan3d import ScanError, scan_height_field

        geo = fsi["geometry"]
        key = f"{where}: forward_model.fsi.geometry"
        if geo.get("height_field"):
            raise ConfigError(f"{key}.height_field is filled from geometry.scan with shape: "
                              "scan; leave it out")
        if fsi["mesh"]["preset"] not in MESH_PRESETS_3D:
            raise ConfigError(f"{where}: forward_model.fsi.mesh.preset: no 3D preset "
                              f"'{fsi['mesh']['preset']}' (3D presets: "
                              f"{', '.join(MESH_PRESETS_3D)})")
        mesh = {**MESH_PRESETS_3D[fsi["mesh"]["preset"]],
                **{k: v for k, v in fsi["mesh"].items() if v is not None}}
        try:
            field = scan_height_field(geo, min_gap=float(mesh["h_interface"]), key=key)
        except ScanError as exc:
            raise ConfigError(str(exc)) from None
        cfg["forward_model"]["fsi"]["geometry"]["height_field"] = field.to_config()
        i = field.info
        return [(f"{key}.scan: the model's biofilm is the colony of '{geo['scan']['path']}' as a "
                 f"height field ({i['grid'][0]} x {i['grid'][1]} nodes at "
                 f"{i['spacing_mm'] * 1e3:.3g} um, smoothed at {i['smoothing_mm'] * 1e3:.3g} um; "
                 f"x = {i['x_range_mm'][0]:.4g} to {i['x_range_mm'][1]:.4g} mm, z = "
                 f"{i['z_range_mm'][0]:.4g} to {i['z_range_mm'][1]:.4g} mm, "
                 f"{i['height_mm']:.4g} mm high)")]

    @staticmethod
    def _validate_scan_not_observed(cfg: dict[str, Any], where: str) -> None:
        """The model's zero-flow scan (``geometry.scan.path``) listed in
        ``observations.files`` at a loading above zero is refused: its colony is the
        model's undeformed biofilm, so the snapshot would be compared with the model
        under that flow as if the flow had not moved it, which pulls the stiffness up
        without a word (the placement and order checks pass: it lies where the model's
        colony is). At factor 0 (or ``load: 0``) it is allowed. Also the other way
        round: a loaded observation given as the zero-flow scan."""
        fm = cfg["forward_model"]
        obs = cfg["observations"]
        geometry = validate(fm["fsi"], "fsi")["geometry"]
        if geometry["shape"] != "scan" or obs["source"] != "files":
            return
        scan = Path(geometry["scan"]["path"])
        if not scan.exists():
            return
        files = obs.get("files") or []
        factors = [float(v) for v in fm["loadings"]["factors"]]
        for k, e in enumerate(files):
            path = Path(e["path"])
            if not path.exists() or not os.path.samefile(path, scan):
                continue
            load = e.get("load")
            factor = factors[k] if len(factors) == len(files) else None
            if (load is not None and float(load) == 0.0) or (load is None and factor == 0.0):
                continue
            at = (f"load {float(load):g}" if load is not None else
                  f"loading factor {factor:g} of forward_model.loadings.factors"
                  if factor is not None else "a loading above zero")
            raise ConfigError(
                f"{where}: observations.files[{k}] ('{path}') is the model's zero-flow scan "
                f"(forward_model.fsi.geometry.scan.path), observed here at {at}: its colony "
                "is the model's undeformed biofilm, so the model under that flow would be "
                "compared with a colony the flow did not move (the stiffness pulled up). "
                "List the scans under flow only, in the order of the loadings (or give "
                "this one load: 0 with a factor 0 in forward_model.loadings.factors); if "
                "this file is a scan under flow, the zero-flow scan is another file")

    @staticmethod
    def _validate_colony_choice(cfg: dict[str, Any], where: str, observed: dict[str, Any],
                                read: dict[str, Any]) -> list[str]:
        """An observation image with several colonies is traced along the largest, or the
        one in its ``colony`` x-range (:func:`~bayescalib.io.observations.read_interface`);
        for the 2D fsi model that must be the colony the model meshes (its undeformed
        biofilm, from ``geometry.scan`` or the default shape). Refused, naming the
        colonies and the ``colony`` x-range to give, when the traced colony overlaps less
        than half of the model's x-extent while another overlaps more (before the extent
        and placement checks, whose words would point at units or the origin); a note
        says which was traced otherwise."""
        if cfg["forward_model"]["type"] != "fsi" or Study.model_dim(cfg) != 2:
            return []
        from bayescalib.io.observations import UNITS

        several = {k: i for k, i in read.items() if len(i.get("colonies_mm") or []) > 1}
        if not several:
            return []
        from bayescalib.models.fsi.geometry import reference_interface

        geometry = validate(cfg["forward_model"]["fsi"], "fsi")["geometry"]
        ref = reference_interface(geometry)
        a, b = float(ref[:, 0].min()), float(ref[:, 0].max())

        def overlap(r: list[float]) -> float:
            return max(0.0, min(r[1], b) - max(r[0], a)) / max(b - a, 1e-12)

        notes = []
        for key, info in several.items():
            entry = dict(_entry_at(cfg, key))
            units = entry.get("units") or "mm"
            f = UNITS[units]
            ranges, k = info["colonies_mm"], info["colony_index"]
            listed = "; ".join(f"x {r[0] / f:.6g} to {r[1] / f:.6g} {units}" for r in ranges)
            best = max(range(len(ranges)), key=lambda j: overlap(ranges[j]))
            if k != best and overlap(ranges[k]) < 0.5 and overlap(ranges[best]) >= 0.5:
                r = ranges[best]
                traced = ("in the given x-range" if entry.get("colony") is not None
                          else "the largest")
                raise ConfigError(
                    f"{where}: {key} ('{entry['path']}') holds {len(ranges)} colonies "
                    f"({listed}); the one traced ({traced}, x {ranges[k][0] / f:.6g} to "
                    f"{ranges[k][1] / f:.6g} {units}) is not the colony the model meshes "
                    f"(its undeformed biofilm spans x {a / f:.6g} to {b / f:.6g} {units}): "
                    f"give {key}.colony: [{r[0] / f:.6g}, {r[1] / f:.6g}] to trace that one")
            notes.append(f"{where}: {key}: {len(ranges)} colonies in the image ({listed}); "
                         f"traced: x {ranges[k][0] / f:.6g} to {ranges[k][1] / f:.6g} {units}"
                         + (" (the largest)" if entry.get("colony") is None else ""))
        return notes

    @staticmethod
    def _validate_registration(cfg: dict[str, Any], where: str, observed: dict[str, Any],
                               read: Mapping[str, Any] | None = None) -> None:
        """Every observed interface lies where the model's undeformed biofilm is, at its
        scale: a flow moves the interface by a fraction of the colony's height and its
        feet barely; a wrong origin or unit moves or scales it as a whole. Refused when
        the observed extent is not within a factor 2 of the model's (units: the x-extent
        of a curve; a surface's x- and z-extents, each), or when its nodes lie on average
        more than a quarter of the colony's height from the model's undeformed interface,
        or (3D) its footprint's centre more than :data:`FOOTPRINT_SHIFT` of the footprint
        from the model's (placement: :func:`bayescalib.geometry.outline.placement`, in 3D
        :func:`bayescalib.geometry.surface.surface_placement`); both before any solve.

        A python or command model's geometry is known only from a solve: its files are
        compared with ``observations.reference`` (units and placement) or, without one,
        with the first file (units: the snapshots of one colony are of one size), and
        that one's size with the likelihood's noise (:meth:`_validate_scale`)."""
        import numpy as np

        from bayescalib.geometry.interface import Interface
        from bayescalib.geometry.outline import downstream_shift, mirrored_x, placement
        from bayescalib.geometry.surface import surface_placement, upper_shift
        from bayescalib.io.observations import UNITS, unit_hint

        if not observed:
            return
        dim = next(iter(observed.values())).dim  # one dimension (_validate_dimension)
        place = True
        if cfg["forward_model"]["type"] == "fsi":
            geometry = validate(cfg["forward_model"]["fsi"], "fsi")["geometry"]
            if dim == 2:
                from bayescalib.models.fsi.geometry import reference_interface

                ref = Interface.polyline(reference_interface(geometry), name="reference")
            else:
                from bayescalib.models.fsi.geometry3d import reference_surface

                ref = reference_surface(geometry)
            what = "the model's undeformed biofilm"
        else:
            what = "observations.reference" if "observations.reference" in observed \
                else next(iter(observed))
            Study._validate_scale(cfg, where, what, observed[what])
            ref = observed[what]
            place = what == "observations.reference"  # snapshots under load move apart
        height = float(np.ptp(ref.points[:, 1])) or 1.0
        if what.startswith("the model"):
            Study._validate_noise_scale(cfg, where, height)
        axes = ((0, "wide"),) if dim == 2 else ((0, "long (x, along the flow)"),
                                                    (2, "wide (z, across the flow)"))
        moved: dict[str, float] = {}  # each snapshot's mean distance from the model's colony
        leans: dict[str, float] = {}  # 3D: each snapshot's downstream lean (surface.upper_shift)
        across: dict[str, float] = {}  # 3D: and its shift across the flow
        mirrors: dict[str, float] = {}  # 2D: its mean distance mirrored in x
        for key, iface in observed.items():
            if key == what:  # the reference compared with itself
                continue
            entry = dict(_entry_at(cfg, key))
            units = entry.get("units") or "mm"
            for ax, word in axes:
                e_obs, e_ref = float(np.ptp(iface.points[:, ax])), float(np.ptp(ref.points[:, ax]))
                ratio = e_obs / (e_ref or 1.0)
                if 0.5 <= ratio <= 2.0:
                    continue
                u = unit_hint(ratio, units, 0.5, 2.0)
                raise ConfigError(
                    f"{where}: {key} ('{entry['path']}'): the observed interface is "
                    f"{ratio:.3g} times as {word} as {what} "
                    f"({e_obs:.4g} mm against {e_ref:.4g} mm, read as {units}): check "
                    f"{key}.units" + (" and pixel_size" if entry.get("pixel_size") is not None
                                      else "")
                    + (f"; the sizes agree if the file is in {u} (units: {u})" if u else "")
                    + ("; or make the model's colony the observed one's size "
                       "(forward_model.fsi.geometry)" if what.startswith("the model") and not u
                       else ""))
            if not place:
                continue
            p = placement(iface.points, ref.points) if dim == 2 else surface_placement(iface, ref)
            moved[key] = float(p.mean_distance)
            if dim == 3:
                leans[key], across[key] = upper_shift(iface, ref)
            else:
                leans[key] = downstream_shift(iface.points, ref.points)
                mirrors[key] = float(placement(mirrored_x(iface.points, ref.points),
                                               ref.points).mean_distance)
            foot = 0.0 if dim == 2 else float(np.hypot(p.offset[0], p.offset[2]))
            span = float(np.mean(np.ptp(ref.points[:, [0, 2]], axis=0))) if dim == 3 else 1.0
            if p.mean_distance > 0.25 * height or foot > FOOTPRINT_SHIFT * span:
                offset = ", ".join(f"{v:+.3f}" for v in p.offset)
                fix = ""
                origin = entry.get("origin")
                if origin is not None and len(origin) == len(p.offset):
                    f = UNITS[units]
                    # 3D: the offset's y is the top's (a flow lowers it); a volume's
                    # substrate is checked on y = 0 on its own, so its y is kept
                    shifted = [o - v / f for o, v in zip(origin, p.offset, strict=True)]
                    if dim == 3:
                        shifted[1] = origin[1]
                    moved = ", ".join(f"{v:.6g}" for v in shifted)
                    fix = f"; with origin [{moved}] {units} it would lie in place"
                elif entry.get("pixel_size") is not None:
                    fix = f"; {key}.origin is not given"
                if dim == 3 and isinstance(entry.get("pixel_size"), list):
                    fix += ("; or the volume's axes are in another order than (B-scan = z, "
                            "row from the top = y, column = x)")
                n = int(((read or {}).get(key) or {}).get("colonies") or 1)
                if dim == 3 and n > 1:
                    fix += (f"; or {key}.component picked another colony: the volume holds "
                            f"{n}, ranked by size (0 the largest), and the ranks may differ "
                            "from one volume to the next: give the one at the model's colony")
                why = (f"its footprint's centre lies {foot:.3g} mm from {what}'s, whose "
                       f"footprint is {span:.3g} mm across: the base, attached to the floor, "
                       "does not move under flow" if foot > FOOTPRINT_SHIFT * span else
                       f"the observed interface lies {p.mean_distance:.3g} mm (mean distance "
                       f"of its nodes) from {what}, whose height is {height:.3g} mm: a flow "
                       "moves it by a fraction of that")
                raise ConfigError(
                    f"{where}: {key} ('{entry['path']}'): {why}. It is offset by about "
                    f"({offset}) mm: check {key}.origin and {key}.units{fix}")
        if what.startswith("the model"):
            Study._validate_mirror(cfg, where, moved, mirrors)
            Study._validate_lean(cfg, where, leans, across)
            Study._validate_snapshot_order(cfg, where, leans if dim == 3 else moved)

    @staticmethod
    def _validate_mirror(cfg: dict[str, Any], where: str, moved: Mapping[str, float],
                         mirrors: Mapping[str, float]) -> None:
        """2D, the model's colony from a zero-flow scan: an observed interface that lies
        more than 2 sigma_N from the model's undeformed colony but less than half as far
        as its mirror image (x reversed, on the colony's footprint) is an image with its
        columns reversed against the zero-flow scan's: refused. The OCT example's scans
        lie 2.2-10.4 um from the colony and 30-34 um mirrored; reversed, the other way
        round. The placement check lets it through (a quarter of the colony's height), and
        the model would be fitted to another colony's shape. A symmetric colony is its own
        mirror image: nothing to tell, and nothing lost."""
        from bayescalib.inference.likelihood import sigma_n2_from_config

        geometry = validate(cfg["forward_model"]["fsi"], "fsi")["geometry"]
        if geometry["shape"] != "scan" or not mirrors:
            return
        sigma = math.sqrt(sigma_n2_from_config(cfg["likelihood"]))
        for key, d in moved.items():
            m = mirrors.get(key)
            if m is not None and d > 2.0 * sigma and m < 0.5 * d:
                path = _entry_at(cfg, key)["path"]
                raise ConfigError(
                    f"{where}: {key} ('{path}'): the observed interface lies {1e3 * d:.3g} um "
                    f"(mean distance of its nodes) from the model's undeformed biofilm but "
                    f"{1e3 * m:.3g} um mirrored (x reversed, on the colony's footprint; the "
                    f"likelihood's sigma_N is {1e3 * sigma:.3g} um): is the image "
                    "mirrored against the zero-flow scan (columns reversed)? Reverse its "
                    "columns, so that all scans run from upstream (column 0) to downstream")

    @staticmethod
    def _validate_lean(cfg: dict[str, Any], where: str, leans: Mapping[str, float],
                       across: Mapping[str, float]) -> None:
        """The model's colony from a zero-flow scan (2D: the height-weighted x-offset of
        the observed nodes, :func:`bayescalib.geometry.outline.downstream_shift`, the most
        loaded by more than sigma_N upstream refuses the same way; 3D as follows). 3D: the
        flow (+x) bends the colony downstream, so observed colonies that all lean upstream of the model's undeformed
        one (:func:`bayescalib.geometry.surface.downstream_lean`), the most loaded by more
        than 2 sigma_N, are refused as mirrored in x (B-scan columns running against the
        flow): the placement and unit checks pass a colony mirrored about its middle,
        and the model would be fitted to a deformation in the opposite direction. And a
        most loaded colony bent across the flow (z) by more than 2 sigma_N and twice its
        lean is refused as a volume with its x and z axes swapped (an array (nx, ny, nz),
        B-scans along the flow): the model's colony from such a volume is swapped too, so
        the size and placement checks pass. Only with ``geometry.shape: scan``: the
        shifts are then measured from the same colony at zero flow (an analytic colony's
        own asymmetry is no flow's)."""
        from bayescalib.inference.likelihood import sigma_n2_from_config

        fm = cfg["forward_model"]
        geometry = validate(fm["fsi"], "fsi")["geometry"]
        files = cfg["observations"]["files"] or []
        keys = [f"observations.files[{k}]" for k in range(len(files))]
        if geometry["shape"] != "scan" or not leans or any(k not in leans for k in keys):
            return
        factors = [float(v) for v in fm["loadings"]["factors"]]
        if len(factors) == len(files) and all(e.get("load") is None for e in files):
            top = keys[max(range(len(factors)), key=lambda k: factors[k])]
        else:
            top = min(keys, key=lambda k: leans[k])
        sigma = math.sqrt(sigma_n2_from_config(cfg["likelihood"]))
        if not across:  # 2D: the height-weighted x-offset, smaller than the 3D lean
            if all(v < 0.0 for v in leans.values()) and leans[top] < -sigma:
                listed = ", ".join(f"{k} {1e3 * leans[k]:+.3g} um" for k in keys)
                raise ConfigError(
                    f"{where}: the observed interfaces have moved upstream of the model's "
                    f"undeformed biofilm ({listed}: the x-offset of their nodes from it, "
                    f"weighted by height; the likelihood's sigma_N is {1e3 * sigma:.3g} um), "
                    "while the flow, along +x, pushes a colony downstream: does the flow "
                    "run against the images' x (columns from downstream to upstream)? "
                    "Reverse the columns of every scan, the zero-flow one included, so that "
                    "column 0 is the upstream side")
            return
        if all(v < 0.0 for v in leans.values()) and leans[top] < -2.0 * sigma:
            listed = ", ".join(f"{k} {1e3 * leans[k]:+.3g} um" for k in keys)
            raise ConfigError(
                f"{where}: the observed colonies lean upstream of the model's undeformed "
                f"biofilm ({listed}: the x-shift of their upper half's centre from their base's; the "
                f"likelihood's sigma_N is {1e3 * sigma:.3g} um), while the flow, along +x, "
                "bends a colony downstream: are the B-scans' columns running against the "
                "flow (x mirrored)? Reverse the columns of the observed volumes (or of "
                "every volume, the zero-flow one included, if its colony is not symmetric), "
                "so that column 0 is the upstream side")
        side = across[top]
        if abs(side) > 2.0 * sigma and abs(side) > 2.0 * abs(leans[top]):
            listed = ", ".join(f"{k} {1e3 * across[k]:+.3g} um across, {1e3 * leans[k]:+.3g} "
                               "um along" for k in keys)
            raise ConfigError(
                f"{where}: the observed colonies bend across the flow (z), not along it "
                f"({listed}: the shift of their upper half's centre from their base's, "
                f"against the model's undeformed biofilm; the likelihood's sigma_N is {1e3 * sigma:.3g} um), "
                "while the flow runs along x: are the volumes' x and z axes swapped (B-scans "
                "taken along the flow, or an array stored (nx, ny, nz))? A volume is (nz, ny, "
                "nx): B-scans across the flow (planes z = const), each a row per depth and a "
                "column per x along the flow; transpose every volume, the zero-flow one "
                "included (pixel_size and origin are of the flow cell's x, y, z)")

    @staticmethod
    def _validate_snapshot_order(cfg: dict[str, Any], where: str,
                                 moved: Mapping[str, float]) -> None:
        """Snapshots are paired with the loadings by their order. A larger flow moves the
        interface farther from the undeformed colony, so files whose mean distance from
        the model's undeformed biofilm (3D: their downstream lean,
        :func:`bayescalib.geometry.surface.downstream_lean`) falls as the loading rises,
        each step by more than half the likelihood's noise sd sigma_N and in all by more
        than 2 sigma_N, are refused as listed in the reverse order (a file's ``load``
        states the order, and the check is skipped then: the loads are checked against
        the loadings). On the OCT example the distances are 2.2, 5.6 and 10.4 um at 50,
        100 and 150 mm^2/s (sigma_N 2 um); on the 3D one (the model's colony from its
        zero-flow volume) the mean distances are 4.2 and 8.2 um at 50 and 100 mm^3/s, a
        step the geometry's own misfit makes too small to tell (sigma_N 3.2 um), the
        leans 5.1 and 14.3 um."""
        from bayescalib.inference.likelihood import sigma_n2_from_config

        files = cfg["observations"]["files"] or []
        factors = [float(v) for v in cfg["forward_model"]["loadings"]["factors"]]
        keys = [f"observations.files[{k}]" for k in range(len(files))]
        if (len(factors) < 2 or len(factors) != len(files) or any(k not in moved for k in keys)
                or any(e.get("load") is not None for e in files)):
            return
        by_load = sorted(range(len(factors)), key=lambda k: factors[k])
        dist = [moved[keys[k]] for k in by_load]
        sigma = math.sqrt(sigma_n2_from_config(cfg["likelihood"]))
        if all(a - b > 0.5 * sigma for a, b in itertools.pairwise(dist)) \
                and dist[0] - dist[-1] > 2.0 * sigma:
            listed = ", ".join(f"{keys[k]} {1e3 * moved[keys[k]]:.3g} um at factor "
                               f"{factors[k]:g}" for k in by_load)
            lean = Study.model_dim(cfg) == 3
            raise ConfigError(
                f"{where}: the observed interfaces "
                + ("lean the farther downstream of" if lean else "lie the farther from")
                + " the model's undeformed "
                f"biofilm the smaller their loading ({listed}; "
                + ("the x-shift of their upper half's centre from their base's" if lean else
                   "mean distance of their nodes")
                + f"; the likelihood's sigma_N is {1e3 * sigma:.3g} um), while a "
                "larger flow moves the interface farther: are observations.files listed in "
                "the reverse order of forward_model.loadings.factors? List them in that "
                "order, or give each file its load to state which loading it is")

    @staticmethod
    def _validate_noise_scale(cfg: dict[str, Any], where: str, height: float) -> None:
        """A likelihood noise sd sigma_N at least the height of the model's undeformed
        colony (mm) is refused: no observed shape could inform the parameters through
        it, and it is the sign of a unit slip (``sigma_n: 2.0`` meant as 2 um; sigma_N is
        in mm). Used for observation files with the fsi model, whose colony is known
        before any solve."""
        from bayescalib.inference.likelihood import sigma_n2_from_config

        lk = cfg["likelihood"]
        sigma_n = math.sqrt(sigma_n2_from_config(lk))
        if sigma_n < height:
            return
        key = "sigma_n" if lk.get("sigma_n") is not None else "sigma_n2"
        given = f"likelihood.{key} = {lk[key]:g}" + (
            f" mm^2 (sigma_N = {sigma_n:.3g} mm)" if key == "sigma_n2" else " mm")
        um = (f"; if it was meant in um, write likelihood.sigma_n: {sigma_n * 1e-3:g} "
              f"(or sigma_n2: {sigma_n2_from_config(lk) * 1e-6:.3g})"
              if sigma_n * 1e-3 < height else "")
        raise ConfigError(
            f"{where}: {given}: the likelihood's noise sd is at least the height of the "
            f"model's undeformed biofilm ({height:.3g} mm), so the observed shapes could "
            "tell nothing about the parameters: sigma_N is in mm (the segmentation error "
            f"plus the model error, typically a few um){um}")

    @staticmethod
    def model_dim(cfg: Mapping[str, Any]) -> int | None:
        """The dimension of the model's interface: 2 or 3 for the fsi model
        (``forward_model.fsi.geometry.dim``); None for a python or command model (known
        only from a solve)."""
        fm = cfg["forward_model"]
        if fm["type"] != "fsi":
            return None
        return int(validate(fm.get("fsi") or {}, "fsi")["geometry"]["dim"])

    @staticmethod
    def _validate_dimension(cfg: dict[str, Any], where: str, observed: dict[str, Any]) -> None:
        """Every observed interface has the dimension of the model's (a 2D curve for the
        2D model, a triangulated surface for the 3D one), and all have the same: a
        mismatch is refused here, before any solve (the discrepancy could not compare
        them). Synthetic observations are the model's own interfaces: nothing to check."""
        dim = Study.model_dim(cfg)
        what = {2: "a 2D curve", 3: "a 3D surface"}
        first = None
        for key, iface in observed.items():
            path = dict(_entry_at(cfg, key))["path"]
            if dim is not None and iface.dim != dim:
                hint = ("give the colony's surface (STL, PLY or VTK polygons) or its OCT "
                        "volume (a folder of B-scans, .npy, a multi-page TIFF) for the 3D "
                        "model, or set forward_model.fsi.geometry.dim: 2"
                        if dim == 3 else
                        "give a 2D interface (coordinates, a VTK polyline or an image) for "
                        "the 2D model, or set forward_model.fsi.geometry.dim: 3")
                raise ConfigError(
                    f"{where}: {key} ('{path}') is {what[iface.dim]}, but the model's "
                    f"interface is {what[dim]} (forward_model.fsi.geometry.dim: {dim}): {hint}")
            if first is None:
                first = (key, path, iface.dim)
            elif iface.dim != first[2]:
                raise ConfigError(
                    f"{where}: {key} ('{path}') is {what[iface.dim]}, but {first[0]} "
                    f"('{first[1]}') is {what[first[2]]}: the observations of one study "
                    "have one dimension")

    @staticmethod
    def _validate_scale(cfg: dict[str, Any], where: str, key: str, iface: Any) -> None:
        """An observed interface smaller than the likelihood's noise sd sigma_N (its
        largest extent, in mm) holds no shape to calibrate on: refused as the unit slip it
        usually is (a file in metres read as mm), naming the unit in which it would span
        between 1 and 10^4 sigma_N. Used where the model's geometry is not known before a
        solve (python and command models); the fsi model's is compared directly."""
        import numpy as np

        from bayescalib.inference.likelihood import sigma_n2_from_config
        from bayescalib.io.observations import UNITS, unit_hint

        sigma_n = math.sqrt(sigma_n2_from_config(cfg["likelihood"]))
        extent = float(np.max(np.ptp(iface.points, axis=0)))
        if extent >= sigma_n:
            return
        entry = dict(_entry_at(cfg, key))
        units = entry.get("units") or "mm"
        u = unit_hint(extent / sigma_n, units, 1.0, 1.0e4)
        raise ConfigError(
            f"{where}: {key} ('{entry['path']}'): the observed interface spans "
            f"{extent:.3g} mm (read as {units}), less than the likelihood's noise sd "
            f"sigma_N = {sigma_n:.3g} mm: an interface smaller than its noise holds no shape "
            f"to calibrate on, the sign of a unit slip. Check {key}.units"
            + (" and pixel_size" if entry.get("pixel_size") is not None else "")
            + (f": in {u} it spans {extent * UNITS[u] / UNITS[units]:.3g} mm (units: {u})"
               if u else ""))

    @staticmethod
    def _validate_observation_files(cfg: dict[str, Any],
                                    where: str) -> tuple[dict[str, Any], dict[str, Any]]:
        """Observation files exist, can be read and hold an interface that fits the
        domain: known before any job. Images are read and segmented here too (the
        observe job does it again; about 10 ms for a 600 x 300 scan), so that an
        unreadable, oversized, all-black or all-white image, a scan whose segmentation
        finds no biofilm, or a missing ``origin`` is a config error, not a failed job.
        Returns the interfaces read and their reading records
        (:func:`~bayescalib.io.observations.read_interface_info`), by config key."""
        from bayescalib.geometry.imaging import inverted
        from bayescalib.io.observations import (
            CSV_SUFFIXES,
            IMAGE_SUFFIXES,
            INTERFACE_SUFFIXES,
            ObservationError,
            image_substrate_offset,
            read_interface_info,
            reader_options,
            validate_shape,
        )
        from bayescalib.io.volumes import is_volume, substrate_offset

        obs = cfg["observations"]
        if obs["source"] != "files":
            return {}, {}
        observed: dict[str, Any] = {}
        read: dict[str, Any] = {}
        entries = [(f"observations.files[{k}]", e) for k, e in enumerate(obs.get("files") or [])]
        if not entries:
            raise ConfigError(f"{where}: observations.files is empty: list at least one "
                              "interface file (one per loading)")
        if obs.get("reference"):
            entries.append(("observations.reference", obs["reference"]))
        for key, e in entries:
            path = Path(e["path"])
            suffix = path.suffix.lower()
            if suffix not in INTERFACE_SUFFIXES and not path.is_dir():
                raise ConfigError(f"{where}: {key}.path: '{path}' is not a supported interface "
                                  f"file (suffixes: {', '.join(sorted(INTERFACE_SUFFIXES))}; "
                                  "or a folder of B-scans, a volume)")
            if path.exists() and is_volume(path) and Study.model_dim(cfg) == 2:
                raise ConfigError(
                    f"{where}: {key} ('{path}') is an OCT volume (a folder of B-scans, a .npy "
                    "array or a multi-page TIFF), but the model's interface is a 2D curve "
                    "(forward_model.fsi.geometry.dim: 2): give one B-scan image (one page) of "
                    "the colony's section for the 2D model, or set "
                    "forward_model.fsi.geometry.dim: 3")
            if path.exists() and is_volume(path):
                Study._validate_volume_entry(where, key, e)
            elif path.exists() and (isinstance(e.get("pixel_size"), list)
                                    or len(e.get("origin") or ()) > 2):
                raise ConfigError(
                    f"{where}: {key}: '{path}' is not a volume (a folder of B-scans, a .npy "
                    "array or a multi-page TIFF), so pixel_size is one number and origin "
                    f"[x, y] (got pixel_size {e.get('pixel_size')!r}, origin "
                    f"{e.get('origin')!r})")
            elif suffix in IMAGE_SUFFIXES and e.get("pixel_size") is None:
                raise ConfigError(f"{where}: {key}.pixel_size is required for the image "
                                  f"'{path}' (the size of one pixel, in {key}.units)")
            if suffix in IMAGE_SUFFIXES and e.get("origin") is None:
                raise ConfigError(
                    f"{where}: {key}.origin is required for the image '{path}': the position "
                    f"[x, y] of the centre of the bottom-left pixel, in {key}.units (e.g. "
                    "[0.0025, 0.0025] mm for an image whose bottom-left corner is at (0, 0) "
                    "with 5 um pixels); there is no default, since (0, 0) puts the image "
                    "half a pixel and its whole offset away from the model")
            if not path.is_file() and not path.is_dir():
                raise ConfigError(f"{where}: {key}.path: '{path}' does not exist"
                                  + (f" (relative paths are read from {Path.cwd()})"
                                     if not path.is_absolute() else ""))
            if path.is_file():
                try:
                    with path.open("rb") as fh:
                        fh.read(1)
                except OSError as exc:
                    raise ConfigError(f"{where}: {key}.path: '{path}' cannot be read "
                                      f"({exc.strerror or exc})") from None
                Study._validate_point_count(cfg, where, key, path)
            opts = reader_options(e)
            try:
                observed[key], info = read_interface_info(path, domain=obs.get("domain"),
                                                          **opts)
                read[key] = info
                validate_shape(observed[key], str(path))
            except ObservationError as exc:
                raise ConfigError(f"{where}: {key}: {exc}") from None
            iface = observed[key]
            if info.get("kind") == "volume" and Study.model_dim(cfg) == 3:
                # the model's floor is y = 0: a volume whose substrate lies elsewhere is
                # misplaced in y, which the placement check lets through up to a quarter
                # of the colony's height
                why = substrate_offset(info, units=e["units"],
                                       pixel_size=e["pixel_size"], origin=e["origin"])
                if why:
                    raise ConfigError(f"{where}: {key} ('{path}'): {why}")
            if Study.model_dim(cfg) == 2 and iface.n_cells == iface.n_points:
                # the model's interface runs from foot to foot: a closed outline adds its
                # base along the floor, which the RKHS measure counts as a misfit
                raise ConfigError(
                    f"{where}: {key} ('{path}'): the observed interface is a closed outline "
                    + ("(its first point repeated last)" if suffix in CSV_SUFFIXES else
                       "(drop_border: false traces along the image's border)"
                       if suffix in IMAGE_SUFFIXES else "(a closed polyline)")
                    + ", but the model's interface is open, from the upstream foot to the "
                    "downstream one on the floor: leave out the base along the floor"
                    + (" (and the repeated point)" if suffix in CSV_SUFFIXES else ""))
            why = inverted(info) if suffix in IMAGE_SUFFIXES else None
            if why and Study.model_dim(cfg) == 2:  # the colony stands on the floor
                raise ConfigError(f"{where}: {key}: {why}")
            if suffix in IMAGE_SUFFIXES and Study.model_dim(cfg) == 2 \
                    and cfg["forward_model"]["type"] == "fsi":
                # the model's feet are on y = 0: an image whose substrate lies elsewhere
                # is misplaced in y, which the placement check lets through
                why = image_substrate_offset(info, units=e["units"],
                                             origin=e["origin"])
                if why:
                    raise ConfigError(f"{where}: {key} ('{path}'): {why}")
            if info.get("border") and Study.model_dim(cfg) == 2:
                # the fsi model's colony stands on the floor with fluid on both sides and
                # above: an observed one that runs into the image's side is cut off there
                # (a python or command model may observe a film across the width)
                band = (info.get("floor") or {}).get("method")
                if info.get("floor_source") == "none" and band in ("bright band",
                                                                    "full-width band"):
                    raise ConfigError(
                        f"{where}: {key} ('{path}'): the traced interface runs along a "
                        f"{band} across the image (the substrate, segmented with the "
                        f"biofilm) into its {' and '.join(info['border'])} border: give "
                        f"{key}.floor: auto (or the substrate's y) to cut the trace there")
                raise ConfigError(
                    f"{where}: {key} ('{path}'): the traced interface runs into the image's "
                    f"{' and '.join(info['border'])} border: the colony is cut by the field "
                    "of view, and the model's interface beyond it would be compared with "
                    "the cut end. Use a scan that shows the whole colony with fluid around it")
        Study._validate_dimension(cfg, where, observed)
        return observed, read

    @staticmethod
    def _pixel_size_notes(cfg: dict[str, Any], where: str) -> list[str]:
        """A note for each observation image whose pixel size (in mm) differs by more
        than 1 % from that of the 2D model's zero-flow scan (``geometry.scan``): the
        scans of one recording share their pixel size, and a wrong one scales the model's
        colony or an observed interface by as much, which the placement check (a quarter
        of the colony's height) lets through up to tens of percent."""
        from bayescalib.io.observations import IMAGE_SUFFIXES, UNITS

        fm = cfg["forward_model"]
        if fm["type"] != "fsi" or cfg["observations"]["source"] != "files":
            return []
        geometry = validate(fm["fsi"], "fsi")["geometry"]
        scan = geometry["scan"] if geometry["shape"] == "scan" else None
        if scan and isinstance(scan["pixel_size"], list):
            return Study._voxel_size_notes(cfg, where, scan)
        if (not scan or Path(scan["path"]).suffix.lower() not in IMAGE_SUFFIXES
                or not isinstance(scan["pixel_size"], (int, float))):
            return []
        s0 = float(scan["pixel_size"]) * UNITS[scan["units"]]
        odd = []
        for k, e in enumerate(cfg["observations"]["files"] or []):
            s = e.get("pixel_size")
            if (Path(e["path"]).suffix.lower() not in IMAGE_SUFFIXES
                    or not isinstance(s, (int, float))):
                continue
            s = float(s) * UNITS[e["units"]]
            if abs(s / s0 - 1.0) > 0.01:
                odd.append(f"observations.files[{k}] {s * 1e3:.4g} um")
        if not odd:
            return []
        return [(f"{where}: pixel_size: {', '.join(odd)}, but the model's zero-flow scan "
                 f"(forward_model.fsi.geometry.scan) has {s0 * 1e3:.4g} um pixels: scans of "
                 "one recording share their pixel size, and a wrong one scales the colony by "
                 "as much (check both)")]

    @staticmethod
    def _voxel_size_notes(cfg: dict[str, Any], where: str, scan: Mapping[str, Any]) -> list[str]:
        """The 3D :meth:`_pixel_size_notes`: each observed volume's voxel size against the
        zero-flow volume's (``geometry.scan.pixel_size``, [dx, dy, dz]), axis by axis. The
        same three sizes in another order is refused (the order is [dx, dy, dz]: a
        [dz, dy, dx] stretches the colony along the flow and shrinks it across, which the
        extent check lets through, and the placement check then names the origin); other
        differences above 1 % are noted."""
        from bayescalib.io.observations import UNITS

        s0 = [float(v) * UNITS[scan["units"]] for v in scan["pixel_size"]]
        um = ", ".join(f"{v * 1e3:.4g}" for v in s0)
        odd = []
        for k, e in enumerate(cfg["observations"]["files"] or []):
            size = e.get("pixel_size")
            if not isinstance(size, list) or len(size) != 3:
                continue
            s = [float(v) * UNITS[e["units"]] for v in size]
            if all(abs(a / b - 1.0) <= 0.01 for a, b in zip(s, s0, strict=True)):
                continue
            given = ", ".join(f"{v * 1e3:.4g}" for v in s)
            if all(abs(a / b - 1.0) <= 0.01 for a, b in zip(sorted(s), sorted(s0), strict=True)):
                raise ConfigError(
                    f"{where}: observations.files[{k}].pixel_size: [{given}] um, the zero-flow "
                    f"volume's voxel size (forward_model.fsi.geometry.scan.pixel_size: [{um}] "
                    "um) in another order: both are [dx, dy, dz], along the B-scan's columns "
                    "(x, the flow), its rows (y, depth) and between B-scans (z); a swap "
                    "stretches the colony along one axis and shrinks it along another. "
                    "Check which of the two is right and give both in that order")
            odd.append(f"observations.files[{k}] [{given}] um")
        if not odd:
            return []
        return [(f"{where}: pixel_size: {', '.join(odd)}, but the model's zero-flow volume "
                 f"(forward_model.fsi.geometry.scan) has [{um}] um voxels: volumes of one "
                 "recording share their voxel size, and a wrong one scales the colony by as "
                 "much along that axis (check both)")]

    @staticmethod
    def _validate_volume_entry(where: str, key: str, entry: Mapping[str, Any]) -> None:
        """A volume's entry gives its voxel size as three numbers and its origin as three
        (no defaults: OCT voxels are rarely cubic, and a missing origin puts the colony
        off the model), and has no 2D image setting that means nothing for it."""
        size, origin = entry.get("pixel_size"), entry.get("origin")
        units = entry.get("units") or "mm"
        path = entry["path"]
        if not isinstance(size, list):
            raise ConfigError(
                f"{where}: {key}.pixel_size: '{path}' is a volume, whose voxel size is three "
                f"numbers [dx, dy, dz] in {units} (along the B-scan's columns, its rows and "
                f"between B-scans), got {size!r}: OCT voxels are rarely cubic, so there is no "
                "one-number form")
        if origin is None or len(origin) != 3:
            raise ConfigError(
                f"{where}: {key}.origin: '{path}' is a volume, whose origin is [x, y, z] in "
                f"{units}, the centre of the first B-scan's bottom-left pixel, got {origin!r} "
                "(there is no default: (0, 0, 0) would put the colony half a voxel and its "
                "whole offset away from the model)")
        if entry.get("drop_border") is False:
            raise ConfigError(f"{where}: {key}.drop_border is a 2D image setting; a volume's "
                              "colony is cut at its floor: leave it out")

    @staticmethod
    def _validate_measure_points(cfg: dict[str, Any], where: str) -> None:
        """The Euclidean measure's file of measurement points (``measure.euclidean.points``)
        exists and holds points, when the study is read: every discrepancy job reads it."""
        from bayescalib.io.observations import ObservationError, count_points, read_points

        path = cfg["measure"]["euclidean"]["points"]
        if "euclidean" not in cfg["measures"] or path is None:
            return
        key = "measure.euclidean.points"
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"{where}: {key}: '{p}' does not exist"
                              + (" as a file (it is a folder)" if p.exists() else "")
                              + (f" (relative paths are read from {Path.cwd()})"
                                 if not p.is_absolute() else ""))
        n = count_points(p, limit=MAX_MEASUREMENT_POINTS)
        if n is not None and n > MAX_MEASUREMENT_POINTS:
            raise ConfigError(
                f"{where}: {key}: '{p}' holds more than {MAX_MEASUREMENT_POINTS:,} measurement "
                "points: each is a line intersected with every solve's interface, and a few "
                "tens are usual (measure.euclidean.n_points: 10 by default)")
        try:
            read_points(p)
        except (ObservationError, OSError) as exc:
            raise ConfigError(f"{where}: {key}: {exc}") from None

    @staticmethod
    def _validate_point_count(cfg: dict[str, Any], where: str, key: str, path: Path) -> None:
        """An observation file of more points than
        :data:`bayescalib.io.observations.MAX_OBSERVATION_POINTS` is refused from its row
        (or VTK header) count, before it is read."""
        from bayescalib.io.observations import MAX_OBSERVATION_POINTS, count_points
        from bayescalib.measures.currents import default_spacing

        n = count_points(path)
        if n is None or n <= MAX_OBSERVATION_POINTS:
            return
        rk = cfg["measure"]["rkhs"]
        h = rk["spacing"] or default_spacing(rk["sigma_w"])
        declared = f"declares {n:,} points, more than" if path.suffix.lower() != ".csv" \
            else "holds more than"
        raise ConfigError(
            f"{where}: {key} ('{path}'): the file {declared} the {MAX_OBSERVATION_POINTS:,} "
            "points an observed interface may have (bayescalib.io.observations."
            "MAX_OBSERVATION_POINTS): the study reads every observation file whenever it is "
            "read, and no measure needs so many"
            + (f" (the RKHS measure resolves {h:g} mm, measure.rkhs.spacing: "
               f"{math.ceil(1.0 / h):,} points per mm of interface)"
               if "rkhs" in cfg["measures"] else "")
            + f"; resample the interface (e.g. to a point every {h:g} mm)")

    @staticmethod
    def _validate_rkhs_cost(cfg: dict[str, Any], where: str, key: str, path: Path,
                         iface: Any) -> None:
        """The RKHS measure's cost guards (``measure.rkhs.max_pairs``, and the most
        elements :func:`bayescalib.measures.currents.current` resamples into) applied to an
        observed interface when the study is read, naming its file, instead of in every
        discrepancy job."""
        from bayescalib.measures import currents

        rk = cfg["measure"]["rkhs"]
        sigma_w, spacing = float(rk["sigma_w"]), rk["spacing"]
        truncate = currents.DEFAULT_TRUNCATE if rk["truncate"] is None else rk["truncate"]
        h = spacing or currents.default_spacing(sigma_w)
        pairs, n_obs, n_model = currents.distance_pairs(iface, sigma_w, spacing, truncate)
        limit = float(rk["max_pairs"])
        elements = currents.MAX_ELEMENTS
        if n_obs > elements:
            raise ConfigError(
                f"{where}: {key} ('{path}'): the RKHS measure would resample the observed "
                f"interface into {n_obs:.3g} elements of at most {h:g} mm (measure.rkhs.sigma_w"
                f" = {sigma_w:g} mm, measure.rkhs.spacing = {spacing}), more than "
                f"{elements:.3g}: check {key}.units, or use a larger sigma_w or spacing")
        if pairs > limit:
            raise ConfigError(
                f"{where}: {key} ('{path}'): one RKHS distance to this interface would "
                f"evaluate about {pairs:.3g} kernel pairs ({n_obs:,.0f} elements of it, "
                f"resampled at {h:g} mm, and about {n_model:,.0f} of a model interface as "
                f"long), above measure.rkhs.max_pairs = {limit:.3g} (the default, 1e10, is "
                f"about a minute on one core, for each solve): the file holds {iface.n_points:,} "
                f"points where {math.ceil(iface.total_measure / h):,} resolve it at "
                f"{h:g} mm; resample it, or raise measure.rkhs.max_pairs")

    @staticmethod
    def _validate_diagnose(cfg: dict[str, Any], where: str) -> None:
        dg = cfg["diagnose"]
        if not dg["enabled"]:
            return
        if dg["candidates"] is None and cfg["forward_model"]["type"] != "fsi":
            raise ConfigError(
                f"{where}: diagnose.candidates is required for a {cfg['forward_model']['type']} "
                "forward model (the built-in candidate library is that of the fsi model)"
            )
        for name, (lo, hi) in dg["priors"].items():
            if not lo < hi:
                raise ConfigError(f"{where}: diagnose.priors.{name}: lo must be < hi, "
                                  f"got {[lo, hi]}")
        for i, c in enumerate(dg["candidates"] or []):
            if c["step"] == 0:
                raise ConfigError(f"{where}: diagnose.candidates[{i}].step must not be 0")
            if not c["prior"][0] < c["prior"][1]:
                raise ConfigError(f"{where}: diagnose.candidates[{i}].prior: lo must be < hi, "
                                  f"got {c['prior']}")

    @staticmethod
    def _validate_loadings(cfg: dict[str, Any], where: str) -> None:
        fm = cfg["forward_model"]
        ld = fm["loadings"]
        factors = ld["factors"]
        if factors == [1.0]:
            if cfg["observations"]["source"] == "files":
                Study._validate_file_loads(cfg, where)
            return
        if len(set(factors)) != len(factors):
            raise ConfigError(f"{where}: forward_model.loadings.factors: duplicate factors in {factors}")
        targets = [p["target"] for p in cfg["parameters"]]
        if fm["type"] == "fsi":
            if ld["parameter"] != "inflow.rate":
                raise ConfigError(f"{where}: forward_model.loadings.parameter: the fsi model "
                                  f"loads 'inflow.rate', not '{ld['parameter']}'")
        elif ld["parameter"] not in targets and ld["nominal"] is None:
            raise ConfigError(
                f"{where}: forward_model.loadings.nominal is required with several "
                f"forward_model.loadings.factors ({factors}): '{ld['parameter']}' is not the "
                "target of a calibrated parameter"
            )
        obs = cfg["observations"]
        if obs["source"] == "files" and len(obs["files"]) != len(factors):
            raise ConfigError(
                f"{where}: observations.files has {len(obs['files'])} file(s) but "
                f"forward_model.loadings.factors has {len(factors)} loadings: give one "
                "snapshot per loading, in the same order"
            )
        if obs["source"] == "files":
            Study._validate_file_loads(cfg, where)

    @staticmethod
    def _validate_file_loads(cfg: dict[str, Any], where: str) -> None:
        """The ``load`` of each observation file, where given, must be its loading's value
        (factor x nominal): snapshots are paired with the loadings by their order, so a
        file listed out of order, or a load in other units, would be compared with the
        solve at another load without a word. With the nominal value unknown (the loaded
        parameter calibrated) the loads must be proportional to the factors."""
        fm = cfg["forward_model"]
        ld = fm["loadings"]
        factors = [float(f) for f in ld["factors"]]
        loads = [e.get("load") for e in cfg["observations"]["files"]]
        if len(loads) != len(factors) or all(v is None for v in loads):
            return
        nominal = ld["nominal"]
        targets = [p["target"] for p in cfg["parameters"]]
        if nominal is None and fm["type"] == "fsi" and ld["parameter"] not in targets:
            fsi = validate(fm.get("fsi") or {}, "fsi", where=f"{where}: forward_model.fsi")
            nominal = fsi["inflow"]["rate"]
        given = [(k, f, float(v)) for k, (f, v) in enumerate(zip(factors, loads, strict=True))
                 if v is not None]
        if nominal is None:  # calibrated: only the ratios are known
            scaled = [v / f for _, f, v in given if f != 0]
            nominal = scaled[0] if scaled else 0.0
        for k, f, v in given:
            want = f * float(nominal)
            if abs(v - want) > 0.01 * max(abs(want), abs(v)):
                raise ConfigError(
                    f"{where}: observations.files[{k}].load is {v:g} but its loading is "
                    f"{want:g} (factor {f:g} x nominal {float(nominal):g} of "
                    f"{ld['parameter']}): the files are paired with the loadings in the order "
                    "listed; list them in the order of forward_model.loadings.factors, or "
                    "correct the load (it is more than 1 % off)")

    @staticmethod
    def _validate_channel_ends(cfg: dict[str, Any], where: str) -> list[str]:
        """The 2D model's colony against the channel's ends: refused nearer the inlet
        than ``MIN_INLET_CLEARANCE`` channel heights (the imposed inflow profile changes
        its deformation by half, and nearer the solves fail); with observed files, a note
        where either foot is nearer its end than ``NOTE_CLEARANCE`` channel heights,
        with the measured change of the deformation and the length and shift that
        advise (:data:`bayescalib.models.fsi.geometry.END_EFFECT`)."""
        from bayescalib.models.fsi import geometry as g

        geo = validate(cfg["forward_model"]["fsi"], "fsi")["geometry"]
        if int(geo["dim"]) != 2:
            return []
        key = f"{where}: forward_model.fsi.geometry"
        up, down = g.channel_ends(geo)
        h, length = float(geo["channel_height"]), float(geo["length"])
        if up <= 0 or down <= 0:
            raise ConfigError(f"{key}: the colony spans x = {up:.4g} to {length - down:.4g} mm, "
                              f"outside the channel (0 to {length:g} mm)")
        def ceil(x: float) -> float:  # to 0.01 mm
            return math.ceil(round(x * 100.0, 6)) / 100.0

        shift = ceil(max(0.0, g.ADVISED_CLEARANCE * h - up))
        longer = ceil(length + shift + max(0.0, g.ADVISED_CLEARANCE * h - down))
        moved = {"half_ellipse": f"geometry.centre {float(geo['centre']) + shift:.4g}",
                 "polyline": f"every x of geometry.outline + {shift:.4g}",
                 "scan": f"the origin's x of geometry.scan and of every observation file + "
                         f"{shift:.4g} mm, in their units"}[geo["shape"]]
        if cfg["observations"].get("domain"):
            moved += ", observations.domain with it"
        advice = (f"geometry.length: {longer:.4g} with the colony {shift:.4g} mm further "
                  f"downstream ({moved})" if shift > 0 else f"geometry.length: {longer:.4g}")
        def off(c: float, end: str) -> str:  # the measured change, "over" below the table
            first = g.END_EFFECT[end][0][0]
            return f"{'over ' if c / h < first else ''}{100 * g.end_effect(c / h, end):.0f} % off"

        if up < g.MIN_INLET_CLEARANCE * h:
            raise ConfigError(
                f"{key}: the colony's upstream foot is {up:.3g} mm from the channel's inlet "
                f"(x = 0), {up / h:.2g} channel heights, where the model imposes the inflow's "
                f"parabolic profile: its deformation would be {off(up, 'inlet')} "
                f"a long flow cell's (measured; at 0.1 channel heights the solves fail). It must lie at "
                f"least {g.MIN_INLET_CLEARANCE:g} channel heights ({g.MIN_INLET_CLEARANCE * h:.3g} mm) "
                f"from the inlet, better {g.ADVISED_CLEARANCE:g}: {advice}")
        if cfg["observations"]["source"] != "files":
            return []  # synthetic data share the model's channel
        near = [f"its {foot} foot is {c:.3g} mm from the channel's {end} ({c / h:.2g} channel "
                f"heights: the deformation {off(c, end)})"
                for foot, end, c in (("upstream", "inlet", up), ("downstream", "outlet", down))
                if c < g.NOTE_CLEARANCE * h]
        if not near:
            return []
        return [(f"{key}: the colony lies near the end of the modelled channel: "
                 f"{' and '.join(near)}, measured against the same colony in a long flow cell "
                 f"(docs/channel_ends.md); the calibrated parameters absorb that difference. "
                 f"At {g.ADVISED_CLEARANCE:g} channel heights from both ends it is below 2 %: "
                 f"{advice}")]

    @staticmethod
    def _validate_boxes(cfg: dict[str, Any], where: str) -> None:
        """Every value of a parameter's design box must be a valid setting of the fsi
        model: each end of each box is set into the fsi section (the others at their
        defaults) and validated, once per study. The schema's limits are intervals, so
        the ends decide; a box reaching past one (nu above 0.5, E at or below 0, a
        target the model does not have) is refused here instead of failing solves."""
        import copy

        from bayescalib.config import set_dotted
        from bayescalib.inference.parameters import ParameterSpace

        fsi = cfg["forward_model"]["fsi"]
        boxes = ParameterSpace.from_config(cfg["parameters"]).bounds
        for k, (par, box) in enumerate(zip(cfg["parameters"], boxes, strict=True)):
            target = par["target"]
            for end, value in zip(("lower", "upper"), box, strict=True):
                trial = copy.deepcopy(fsi)
                try:
                    set_dotted(trial, target, float(value))
                    validate(trial, "fsi")
                except ConfigError as exc:
                    raise ConfigError(
                        f"{where}: parameters[{k}] ('{par['name']}'): the {end} bound {value:g} of "
                        f"its box is not a valid value of its target '{target}' in the fsi model "
                        f"(forward_model.type: fsi): "
                        f"{str(exc).splitlines()[-1].strip()}") from None

    @staticmethod
    def _validate_hidden(cfg: dict[str, Any], where: str) -> None:
        hidden = cfg["observations"].get("hidden") or {}
        if not hidden:
            return
        if cfg["observations"]["source"] != "synthetic":
            raise ConfigError(f"{where}: observations.hidden needs observations.source synthetic")
        if cfg["forward_model"]["type"] != "fsi":
            return  # passed to the python/command model as extra parameters
        from bayescalib.models.fsi.model import FSIModel

        try:  # the checks of a solve with these overrides (validation, physics switches)
            FSIModel(cfg["forward_model"]["fsi"]).resolved_config(hidden)
        except ConfigError as exc:
            raise ConfigError(f"{where}: observations.hidden: {exc}") from None

    # ------------------------------------------------------------------- paths
    @property
    def name(self) -> str:
        return self.config["study"]

    @property
    def root(self) -> str:
        return f"{self.config['results_dir']}/{self.name}"

    @property
    def measures(self) -> list[str]:
        return list(self.config["measures"])

    @property
    def primary_measure(self) -> str:
        return self.config["measures"][0]

    @property
    def active(self) -> bool:
        """True for the active design (rounds chosen by the posterior)."""
        return self.config["design"]["strategy"] == "active"

    @property
    def n_train(self) -> int:
        """Training points of the fixed design; for the active design, its budget."""
        if self.active:
            return int(self.config["design"]["active"]["max_solves"])
        return int(self.config["design"]["n_train"])

    @property
    def n_sobol(self) -> int:
        """Points taken from the Sobol sequence: the whole fixed design (with its
        held-out test points), or round 0 of the active design."""
        if self.active:
            return int(self.config["design"]["active"]["n_initial"])
        return self.n_points

    @property
    def round_smc(self) -> dict[str, Any]:
        """SMC settings of the active rounds (:func:`bayescalib.config.round_smc`)."""
        return round_smc(self.config["smc"], self.config["design"]["active"])

    @property
    def n_test(self) -> int:
        if not self.config["convergence"]["enabled"]:
            return 0
        return int(self.config["design"]["n_test"])

    @property
    def n_points(self) -> int:
        """Number of design points solved: training points plus held-out test points."""
        return self.n_train + self.n_test

    # ----------------------------------------------------------------- design
    @cached_property
    def space(self):
        from bayescalib.inference.parameters import ParameterSpace

        return ParameterSpace.from_config(self.config["parameters"])

    @cached_property
    def _design(self):
        from bayescalib.inference.design import sobol_design

        return sobol_design(self.space.bounds, self.n_sobol, self.config["design"]["seed"])

    def targets(self) -> list[str]:
        """Forward-model config key set by each parameter (its name if none was given)."""
        return [p["target"] for p in self.config["parameters"]]

    def point(self, i: int) -> dict[str, float]:
        """Values of Sobol design point ``i < n_sobol`` keyed by target (plain floats)."""
        if not 0 <= int(i) < self.n_sobol:
            raise IndexError(f"design point {i} is not one of the {self.n_sobol} Sobol points")
        return self.point_values(self._design[int(i)])

    def point_values(self, row) -> dict[str, float]:
        """A design point's values (in parameter order) keyed by target."""
        return {t: float(v) for t, v in zip(self.targets(), row, strict=True)}

    def ground_truth(self) -> dict[str, float]:
        """Ground-truth values keyed by target (for synthetic observations)."""
        return {
            p["target"]: float(p["ground_truth"])
            for p in self.config["parameters"]
            if p.get("ground_truth") is not None
        }

    @property
    def has_ground_truth(self) -> bool:
        """Whether every parameter has a ground truth (synthetic data, or files made
        from known values): only then do figures, captions and summary.json show one."""
        return all(p.get("ground_truth") is not None for p in self.config["parameters"])

    @property
    def observation_paths(self) -> list[str]:
        """The files the observation set is read from (``observations.files`` and the
        reference; a folder volume's B-scans, each): a changed one makes a new set."""
        from bayescalib.io.volumes import volume_files

        obs = self.config["observations"]
        entries = [*obs["files"], *([obs["reference"]] if obs["reference"] else [])]
        return [str(f) for e in entries for f in volume_files(e["path"])]

    @property
    def image_files(self) -> list[str]:
        """The observation files that are 2D images (a mask or a raw B-scan, one page),
        whose segmentation the segmentation figure shows; a volume (a multi-page TIFF)
        is not one."""
        from bayescalib.io.observations import IMAGE_SUFFIXES
        from bayescalib.io.volumes import is_volume

        if self.synthetic:
            return []
        return [e["path"] for e in self.config["observations"]["files"]
                if Path(e["path"]).suffix.lower() in IMAGE_SUFFIXES
                and not is_volume(e["path"])]

    @property
    def interface_dim(self) -> int:
        """The dimension of the fsi model's interface (``geometry.dim``); 2 for a python
        or command model (its dimension is known only from a solve; the figures read it
        from the interfaces themselves)."""
        return Study.model_dim(self.config) or 2

    @property
    def synthetic(self) -> bool:
        """Whether the observations are synthetic (a forward solve at the ground truth)."""
        return self.config["observations"]["source"] == "synthetic"

    def ground_truth_point(self) -> dict[str, Any]:
        """Inputs of the ground-truth solve: the ground truth plus ``observations.hidden``
        (hidden physics switched on only for the synthetic data)."""
        return {**self.ground_truth(), **dict(self.config["observations"].get("hidden") or {})}

    def prior_centre(self) -> dict[str, float]:
        """Centre of the design box, keyed by target (warm-start base state)."""
        b = self.space.bounds
        return {t: float(0.5 * (lo + hi)) for t, (lo, hi) in zip(self.targets(), b, strict=True)}

    # --------------------------------------------------------------- sections
    def section(self, *keys: str) -> dict[str, Any]:
        """Deep copy of the named top-level sections, as plain values."""
        return {k: copy.deepcopy(self.config[k]) for k in keys}

    def forward_section(self) -> dict[str, Any]:
        """The forward model section, reduced to what the chosen model uses."""
        fm = copy.deepcopy(self.config["forward_model"])
        kind = fm["type"]
        for other in ("fsi", "python", "command"):
            if other != kind:
                fm.pop(other, None)
        if fm["loadings"]["factors"] == [1.0]:
            fm.pop("loadings")  # a single loading: nothing for the solve to depend on
        return fm
