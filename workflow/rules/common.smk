# Functions and constants of the rules (Snakemake's lint: rules and functions apart).
# Everything here is cheap at parse time: no design point, round record or file is
# read until the DAG asks for it (checkpoints are consulted lazily).



# ---- Observations

def _observe_inputs(wildcards):
    if study.synthetic:
        return {"run": f"{R}/observations/ground_truth_run.h5"}
    # the files themselves: a changed observation file makes a new observation set
    return {"files": study.observation_paths}


FIELDS = study.config["plots"]["fields"] and study.config["forward_model"]["type"] == "fsi"
# a 3D model's fields figure is their section by the colony's mid-plane z = z_c (the
# plane of a B-scan); None in 2D
SECTION_Z = None
if FIELDS and study.interface_dim == 3:
    from bayescalib.models.fsi.slice2d import midplane_z

    SECTION_Z = midplane_z(study.config["forward_model"]["fsi"]["geometry"])
# synthetic data: a forward solve at the ground truth makes them (rule ground_truth,
# whose fields the fields figure shows); real data have none: the fields figure shows
# the solve at the posterior mean (rule posterior_mean_solve)
SYNTHETIC = study.synthetic

# the observation files that are images (a mask or a raw scan): the segmentation figure
IMAGE_FILES = study.image_files


# ---- Active design: rounds, their records and points

ACTIVE_DIR = f"{R}/active"


def _acquire_path(r):
    return f"{ACTIVE_DIR}/{int(r)}/acquire.json"


_ACQUIRE_CACHE = {}


def _read_acquire(r):
    """The record of active round r (runs the checkpoint first when needed); read once
    per version of the file (point_round reads the records for every design point).
    A record that cannot be read is set aside, so that the next run makes it again
    (bayescalib.stages.files.read_stage_file)."""
    import os

    from bayescalib.stages.files import read_stage_file

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
    return {"run_paths": [f"{R}/runs/{i}.h5" for i in range(n)],
            "disc_paths": [f"{R}/discrepancy/{m}/{i}.json" for i in range(n)]}


# ---- Solves

def _solve_inputs(wildcards):
    out = {}
    if study.config["forward_model"]["warm_start"] == "prior_centre":
        out["base"] = f"{R}/runs/base_state.state.npz"
    return out


def _chosen_by(wildcards):
    """The active round record that chose design point i (none for a Sobol point): an
    input of its solve, not an argument."""
    src = point_source(wildcards.i)
    return [] if src is None else ancient(src)


# ---- Jobs through the run's job server (bayescalib.execution.jobserver)
# The per-point jobs (solve, discrepancy), the per-round and per-measure ones (gather,
# train_surrogate, smc, acquire, marginalize), the posterior check, summary.json and the
# figures have one command: `shell: job(locals())` (or `job(locals(), "<stage>")` where the
# stage is not the rule's name). In the job it is `scripts/job.py` with the job's document,
# one JSON argument: the rule's *named* inputs, outputs and params, which are the keyword
# arguments of the stage's function (jobserver.STAGES), its log, its benchmark file (the
# `benchmark=` log entry: the client writes what the working process cost there) and its
# resources.mem_mb (the working process's memory limit; Snakemake's `benchmark:` would
# measure the client, and --benchmark-repeats does not apply). Unnamed entries are Snakemake's
# only: rerun triggers and report files. A stage parameter is added to the stage function
# and the rule, nowhere else. The client hands the job to the warm server started in
# onstart, or runs it itself when there is none. Snakemake reruns the jobs of a shell
# command whose text changed; the text it records (jobserver.JOB_TEMPLATE) names the
# interpreter and the client through environment variables that the workflow sets here
# (not the user): it holds no path of this machine, and a moved checkout or another venv
# reruns nothing.

from bayescalib.execution.jobserver import export_job_command, job_command as job

export_job_command(workflow.basedir, conda=any(
    getattr(m, "name", str(m)).lower() == "conda"
    for m in getattr(workflow.deployment_settings, "deployment_method", ())))

# The solve rule keeps, as the code Snakemake records for it, the command text it had
# before the job document (`job(locals(), recorded=...)`): the job's work is the same, and
# a changed text would solve every design point of the studies already run again (a
# point is never solved twice). Snakemake formats it for `--printshellcmds` and its
# records, so its names must stay those of the rule. (The discrepancies, a tenth of a
# second each, were computed again once: their inputs are named as the stage's.)
_WARM = study.config["forward_model"]["warm_start"] == "prior_centre"
SOLVE_RECORDED = (
    '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT" solve log {log:q} out {output:q}'
    " forward_model {params.forward_model!r:q} point {params.point!r:q}"
    f"{' base {input.base:q}' if _WARM else ''}"
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

