# Functions and constants of the rules (Snakemake's lint: rules and functions apart).
# Everything here is cheap at parse time: no design point, round record or file is
# read until the DAG asks for it (checkpoints are consulted lazily).



# ---- Observations

def _observe_inputs(wildcards):
    obs = study.config["observations"]
    if study.synthetic:
        return {"run": f"{R}/observations/ground_truth_run.h5"}
    # the files themselves: a changed observation file makes a new observation set
    files = [e["path"] for e in obs["files"]]
    return {"files": files + ([obs["reference"]["path"]] if obs["reference"] else [])}


FIELDS = study.config["plots"]["fields"] and study.config["forward_model"]["type"] == "fsi"
# synthetic data: a forward solve at the ground truth makes them (rule ground_truth,
# whose fields the fields figure shows); real data have none: the fields figure shows
# the solve at the posterior mean (rule posterior_mean_solve)
SYNTHETIC = study.synthetic

# the observation files that are images (a mask or a raw scan): the segmentation figure
IMAGE_FILES = [
    e["path"] for e in study.config["observations"]["files"]
    if not study.synthetic
    and os.path.splitext(e["path"])[1].lower() in (".png", ".tif", ".tiff")
]


# ---- Active design: rounds, their records and points

ACTIVE_DIR = f"{R}/active"


def _acquire_path(r):
    return f"{ACTIVE_DIR}/{int(r)}/acquire.json"


_ACQUIRE_CACHE = {}


def _read_acquire(r):
    """The record of active round r (runs the checkpoint first when needed); read once
    per version of the file (point_round reads the records for every design point).
    A record that cannot be read is set aside, so that the next run makes it again
    (bayescalib.stages.read_stage_file)."""
    import os

    from bayescalib.stages import read_stage_file

    path = checkpoints.acquire.get(r=int(r)).output[0]
    key = (path, os.stat(path).st_mtime_ns)
    if key not in _ACQUIRE_CACHE:
        _ACQUIRE_CACHE[key] = read_stage_file(path, "active round record")
    return _ACQUIRE_CACHE[key]


def final_round():
    """Index of the last active round: the first whose record says stop."""
    r = 0
    while not _read_acquire(r)["stop"]:
        r += 1
    return r


def round_size(r):
    """Number of design points after active round r: round 0's Sobol points, then each
    round's batch as the record before it chose it (a batch, or a check round of
    posterior_check.draws posterior draws: rounds differ in size)."""
    if int(r) == 0:
        return study.n_sobol
    rec = _read_acquire(int(r) - 1)
    return int(rec["n_solves"]) + len(rec["next"]["points"])


def point_round(i):
    """(active round, position in its batch) of design point i >= n_sobol: the records
    are read in order until one's batch holds it."""
    r = 0
    while True:
        rec = _read_acquire(r)
        if rec["stop"]:
            raise ValueError(f"design point {i} lies beyond the final active round {r}")
        end = int(rec["n_solves"]) + len(rec["next"]["points"])
        if int(i) < end:
            return r + 1, int(i) - int(rec["n_solves"])
        r += 1


def final_points():
    """Indices of the design points of the final design."""
    if not study.active:
        return list(range(study.n_points))
    return list(range(round_size(final_round())))


def active_records():
    """Paths of all active rounds' records (empty for a fixed design)."""
    if not study.active:
        return []
    return [_acquire_path(r) for r in range(final_round() + 1)]


def point_source(i):
    """The acquire record that chose design point i (None for a Sobol point)."""
    if int(i) < study.n_sobol:
        return None
    r, _ = point_round(int(i))
    return checkpoints.acquire.get(r=r - 1).output[0]


def point_values(i):
    """Values of design point i keyed by target."""
    if point_source(i) is None:
        return study.point(int(i))
    r, j = point_round(int(i))
    return study.point_values(_read_acquire(r - 1)["next"]["points"][j])


def _round_reuse(wildcards, *names):
    """The last active round's files that a stage of the primary measure reuses when its
    input is the same as the round's (the measure's training table is the last round's
    once the design stops, so its surrogate and particles would be too): [input,
    output] of the round's job, or [] (other measures, a fixed design)."""
    if not study.active or wildcards.measure != study.primary_measure:
        return []
    r = final_round()
    return [f"{ACTIVE_DIR}/{r}/{n}.h5" for n in names]


def _round_inputs(wildcards):
    n = round_size(int(wildcards.r))
    m = study.primary_measure
    return {"runs": [f"{R}/runs/{i}.h5" for i in range(n)],
            "disc": [f"{R}/discrepancy/{m}/{i}.json" for i in range(n)]}


# ---- Solves

def _solve_inputs(wildcards):
    out = {}
    if study.config["forward_model"]["warm_start"] == "prior_centre":
        out["base"] = f"{R}/runs/base_state.state.npz"
    src = point_source(wildcards.i)  # active design: the round record that chose it
    if src is not None:
        out["chosen_by"] = ancient(src)
    return out


# ---- Jobs through the run's job server (bayescalib.execution.jobserver)
# The per-point jobs (solve, discrepancy) and the per-round and per-measure ones
# (train_surrogate, smc, acquire, marginalize) run `scripts/job.py`, a standard-library
# client that hands the job (its params as Python literals: `{params.x!r:q}`, the repr
# quoted) to the warm server started in onstart, or runs it in-process when there is
# none. Snakemake reruns the jobs of a shell command whose text changed, so the text
# names the interpreter and the client through environment variables that the
# workflow sets here (not the user): it holds no path of this machine, and a moved
# checkout or another venv reruns nothing.

from bayescalib.execution.jobserver import export_job_command

export_job_command(workflow.basedir, conda=any(
    getattr(m, "name", str(m)).lower() == "conda"
    for m in getattr(workflow.deployment_settings, "deployment_method", ())))
_WARM = study.config["forward_model"]["warm_start"] == "prior_centre"
SOLVE_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" solve log {log:q} out {output:q}'
    " forward_model {params.forward_model!r:q} point {params.point!r:q}"
    f"{' base {input.base:q}' if _WARM else ''}"
)
# an active round's fit: previous is the previous round's surrogate (none in round 0),
# whose discrete choices it refits between full searches (surrogate.reselect_growth,
# surrogate.reselect_error); a full search fits its candidates on the job's threads
TRAIN_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT"'
    " train_surrogate log {log:q} out {output:q} training {input.training:q}"
    " surrogate {params.surrogate!r:q} parameters {params.parameters!r:q}"
    " previous [ {input.previous:q} ]"
)
# the primary measure's train_surrogate and smc may reuse the last round's output
TRAIN_MEASURE_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT"'
    " train_surrogate log {log:q} out {output:q} training {input.training:q}"
    " surrogate {params.surrogate!r:q} parameters {params.parameters!r:q}"
    " reuse [ {input.reuse:q} ]"
)
SMC_MEASURE_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT"'
    " smc log {log:q} out {output:q} surrogate {input.surrogate:q} smc {params.smc!r:q}"
    " parameters {params.parameters!r:q} reuse [ {input.reuse:q} ]"
)
SMC_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT"'
    " smc log {log:q} out {output:q} surrogate {input:q} smc {params.smc!r:q}"
    " parameters {params.parameters!r:q}"
)
# previous (no file in round 0) comes last: an empty value drops only itself
ACQUIRE_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT"'
    " acquire log {log:q} out {output:q} round {params.round}"
    " training {input.training:q} surrogate {input.surrogate:q}"
    " particles {input.particles:q} active {params.active!r:q} check {params.check!r:q}"
    " parameters {params.parameters!r:q} previous {input.previous:q}"
)
MARGINALIZE_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT"'
    " marginalize log {log:q} out {output.posterior:q} netcdf {output.netcdf:q}"
    " particles {input.particles:q} surrogate {input.surrogate:q}"
    " posterior {params.posterior!r:q} parameters {params.parameters!r:q} seed {params.seed}"
)
# gather_round, gather: the runs and discrepancy records as lists (`[ ... ]`, read by
# bayescalib.execution.jobserver.parse_args); set_aside is a rerun trigger only
GATHER_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" gather log {log:q} out {output:q}'
    " names {params.names!r:q} targets {params.targets!r:q} n_train {params.n_train!r:q}"
    " runs [ {input.runs:q} ] disc [ {input.disc:q} ]"
)
POSTERIOR_CHECK_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" posterior_check log {log:q}'
    " out {output:q} samples [ {input.samples:q} ] obs {input.obs:q}"
    " surrogate {input.surrogate:q} measure_name {params.measure_name:q}"
    " measure {params.measure!r:q} likelihood {params.likelihood!r:q}"
    " parameters {params.parameters!r:q} check {params.check!r:q}"
    " particles {input.particles:q}"
)
PREDICTIVE_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" predictive_solve log {log:q}'
    " out {output:q} particles {input.particles:q} parameters {params.parameters!r:q}"
    " k {wildcards.k} n {params.n} seed {params.seed}"
    " forward_model {params.forward_model!r:q}"
)
# summary.json (the round server, which has scipy.stats imported for the fit check: the
# last job of a run, it had been a script job that imported Snakemake)
SUMMARY_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" summary log {log:q} out {output:q}'
    " study {params.study:q} parameters {params.parameters!r:q}"
    " measures {params.measures!r:q} figure_map {params.figure_map!r:q}"
    " root {params.root:q} strategy {params.strategy:q} n_solves {params.n_solves}"
    " budget {params.budget!r:q}"
    " posterior [ {input.posterior:q} ] training [ {input.training:q} ]"
    " particles [ {input.particles:q} ] active [ {input.active:q} ]"
    " convergence [ {input.convergence:q} ] check [ {input.check:q} ]"
)
# figures (the round server: Matplotlib imported once per run)
FIG_RESPONSE_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" fig_response log {log:q}'
    " training {input.training:q} surrogate {input.surrogate:q}"
    " parameters {params.parameters!r:q} plots {params.plots!r:q} stem {params.stem:q}"
)
FIG_CONVERGENCE_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" fig_convergence log {log:q}'
    " convergence {input:q} plots {params.plots!r:q} stem {params.stem:q}"
)
FIG_POSTERIOR_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" fig_posterior log {log:q}'
    " particles {input.particles:q} posterior {input.posterior:q}"
    " parameters {params.parameters!r:q} plots {params.plots!r:q} stems {params.stems!r:q}"
)
FIG_INTERFACES_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" fig_interfaces log {log:q}'
    " obs {input.obs:q} plots {params.plots!r:q} stem {params.stem:q}"
    + (" truth {input.truth:q}" if SYNTHETIC else "")
    + " samples [ {input.samples:q} ]"
)
FIG_FIELDS_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" fig_fields log {log:q}'
    " vtu {input.vtu:q} run {input.run:q} plots {params.plots!r:q} stem {params.stem:q}"
    + ("" if SYNTHETIC else " at posterior_mean parameters {params.parameters!r:q}")
)
# the solve at the posterior mean, with its fields (real data: the fields figure)
POSTERIOR_MEAN_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" posterior_mean_solve log {log:q}'
    " out {output.run:q} vtu {output.vtu:q} posterior {input.posterior:q}"
    " parameters {params.parameters!r:q} forward_model {params.forward_model!r:q}"
)
FIG_SEGMENTATION_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" fig_segmentation log {log:q}'
    " obs {input.obs:q} observations {params.observations!r:q}"
    " plots {params.plots!r:q} stem {params.stem:q}"
)
FIG_ROUNDS_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" fig_rounds log {log:q}'
    " training {input.training:q} parameters {params.parameters!r:q}"
    " active {params.active!r:q} plots {params.plots!r:q} stem {params.stem:q}"
    " records [ {input.records:q} ] particles [ {input.particles:q} ]"
)
DISCREPANCY_JOB = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" discrepancy log {log:q}'
    " out {output:q} run {input.run:q} obs {input.obs:q}"
    " measure_name {wildcards.measure:q} measure {params.measure!r:q}"
    " likelihood {params.likelihood!r:q}"
)


# ---- Discrepancies

def _set_aside(wildcards):
    """Run records and discrepancy files found corrupt and set aside (renamed to
    *.corrupt by the job that read them). Snakemake does not recompute a missing
    intermediate file while the results built from it are present, so this list is
    a parameter of gather: when it grows, gather reruns, which re-solves exactly the
    points set aside, and everything downstream follows."""
    from pathlib import Path

    found = [f"runs/{p.name}" for p in Path(R, "runs").glob("*.corrupt")]
    found += [p.name for p in Path(R, "discrepancy", wildcards.measure).glob("*.corrupt")]
    return sorted(found)


# ---- Figures

FMT = study.config["plots"]["formats"]
K = study.config["plots"]["n_interface_samples"]  # drawn in the interface figure
# posterior draws solved (predictive_solve): the figure's, and with a fixed design the
# final posterior check's (an active design checks its posterior inside the rounds)
N_CHECK = 0 if study.active else study.config["posterior_check"]["draws"]
K_SOLVED = max(K, N_CHECK)
DIM = len(study.config["parameters"])


def shown(files):
    """The files of a figure that the HTML report embeds: the PNG (each figure once),
    or every format when there is none; the others are kept on disk only."""
    png = [f for f in files if f.endswith(".png")]
    return png or list(files)


def kept(files):
    """The files of a figure written to disk but not embedded in the report."""
    return [f for f in files if f not in shown(files)]


def _fig(name, measure=None):
    base = f"{R}/figures/{measure}/{name}" if measure else f"{R}/figures/{name}"
    return [f"{base}.{ext}" for ext in FMT]


def figure_map():
    """Figure family -> list of files (for summary.json and rule all)."""
    out = {}
    for m in study.measures:
        if DIM >= 2:
            out[f"{m}/response"] = _fig("response", m)
            out[f"{m}/joint"] = _fig("joint", m)
            out[f"{m}/particles"] = _fig("particles", m)
        out[f"{m}/marginals"] = _fig("marginals", m)
        if DIM >= 3:  # with two parameters the joint figure shows all they would
            out[f"{m}/pairs"] = _fig("pairs", m)
            out[f"{m}/parallel"] = _fig("parallel", m)
        if study.config["convergence"]["enabled"]:
            out[f"{m}/convergence"] = _fig("convergence", m)
    if study.active and DIM >= 2:
        out["rounds"] = _fig("rounds")
    if K > 0:
        out["interfaces"] = _fig("interfaces")
    if FIELDS:
        out["fields"] = _fig("fields")
    if IMAGE_FILES:
        out["segmentation"] = _fig("segmentation")
    return out


def figure_targets():
    return [f for files in figure_map().values() for f in files]


# pairs and parallel axes only from three parameters on: for two they repeat the joint
_POSTERIOR_FAMILIES = (["joint", "particles"] if DIM >= 2 else []) + ["marginals"] + (
    ["pairs", "parallel"] if DIM >= 3 else [])


# ---- Diagnosis

def _diagnose_inputs(wildcards):
    m = study.primary_measure
    out = {
        "particles": f"{R}/{m}/particles.h5",
        "training": f"{R}/{m}/training.h5",
        "posterior": f"{R}/{m}/posterior.json",
        "obs": f"{R}/observations/observations.h5",
    }
    if study.config["forward_model"]["warm_start"] == "prior_centre":
        out["base"] = f"{R}/runs/base_state.state.npz"
    out["rounds"] = active_records()
    return out


# ---- Every result file

def study_outputs(wildcards):
    """Every file the results are built from. They are targets too: Snakemake does not
    rebuild a missing intermediate while what was built from it is present, so a
    deleted run record, training table, surrogate, ... would otherwise leave a hole
    under an intact summary.json ("Nothing to be done"). As targets, a missing one is
    rebuilt, and everything built from it follows (newer input)."""
    pts = final_points()
    files = [f"{R}/observations/observations.h5"]
    files += [f"{R}/runs/{i}.h5" for i in pts]
    for m in study.measures:
        files += [f"{R}/discrepancy/{m}/{i}.json" for i in pts]
        files += [f"{R}/{m}/{name}" for name in
                  ("training.h5", "surrogate.h5", "particles.h5", "posterior.json", "posterior.nc")]
    if study.active:
        for r in range(final_round() + 1):
            files += [f"{ACTIVE_DIR}/{r}/{name}" for name in
                      ("training.h5", "surrogate.h5", "particles.h5", "acquire.json")]
    return files

