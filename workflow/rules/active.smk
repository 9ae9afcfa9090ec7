# Active design (design.strategy: active): round 0 solves the Sobol points
# 0..n_initial-1; at the end of each round r the checkpoint `acquire` checks the
# surrogate against round r's solves, applies the stop rule and, unless it
# stops, chooses the batch of round r+1, whose points are solved as ordinary
# `solve` jobs (runs/<i>.h5, i continuing the numbering). Each round's training
# table, surrogate and SMC live under active/<r>/ and use the primary measure.
# A solve depends on its point's values (a parameter), never on the time stamp
# of the acquire file that chose it, so rerunning an acquire job with the same
# outcome re-solves nothing.

import json as _json

ACTIVE_DIR = f"{R}/active"


def _acquire_path(r):
    return f"{ACTIVE_DIR}/{int(r)}/acquire.json"


def _read_acquire(r):
    """The record of active round r (runs the checkpoint first when needed)."""
    path = checkpoints.acquire.get(r=int(r)).output[0]
    with open(path) as fh:
        return _json.load(fh)


def final_round():
    """Index of the last active round: the first whose record says stop."""
    r = 0
    while not _read_acquire(r)["stop"]:
        r += 1
    return r


def final_points():
    """Indices of the design points of the final design."""
    if not study.active:
        return list(range(study.n_points))
    return list(range(study.round_size(final_round())))


def active_records():
    """Paths of all active rounds' records (empty for a fixed design)."""
    if not study.active:
        return []
    return [_acquire_path(r) for r in range(final_round() + 1)]


def point_source(i):
    """The acquire record that chose design point i (None for a Sobol point)."""
    if int(i) < study.n_sobol:
        return None
    r, _ = study.point_round(int(i))
    return checkpoints.acquire.get(r=r - 1).output[0]


def point_values(i):
    """Values of design point i keyed by target."""
    src = point_source(i)
    if src is None:
        return study.point(int(i))
    r, j = study.point_round(int(i))
    with open(src) as fh:
        return study.point_values(_json.load(fh)["next"]["points"][j])


def _round_inputs(wildcards):
    n = study.round_size(int(wildcards.r))
    m = study.primary_measure
    return {"runs": [f"{R}/runs/{i}.h5" for i in range(n)],
            "disc": [f"{R}/discrepancy/{m}/{i}.json" for i in range(n)]}


rule gather_round:
    input:
        unpack(_round_inputs),
    output:
        f"{ACTIVE_DIR}/{{r}}/training.h5",
    params:
        names=[p["name"] for p in study.config["parameters"]],
        targets=study.targets(),
        n_train=None,
    benchmark:
        f"{R}/benchmarks/gather/round_{{r}}.tsv"
    log:
        f"{R}/logs/active/{{r}}/gather.log",
    script:
        "../../scripts/gather.py"


rule train_round:
    input:
        f"{ACTIVE_DIR}/{{r}}/training.h5",
    output:
        f"{ACTIVE_DIR}/{{r}}/surrogate.h5",
    params:
        surrogate=study.config["surrogate"],
        parameters=study.config["parameters"],
    benchmark:
        f"{R}/benchmarks/train_surrogate/round_{{r}}.tsv"
    log:
        f"{R}/logs/active/{{r}}/train_surrogate.log",
    threads: 1
    script:
        "../../scripts/train_surrogate.py"


rule smc_round:
    input:
        f"{ACTIVE_DIR}/{{r}}/surrogate.h5",
    output:
        f"{ACTIVE_DIR}/{{r}}/particles.h5",
    params:
        smc=study.config["smc"],
        parameters=study.config["parameters"],
    benchmark:
        f"{R}/benchmarks/smc/round_{{r}}.tsv"
    log:
        f"{R}/logs/active/{{r}}/smc.log",
    threads: 1
    script:
        "../../scripts/smc.py"


checkpoint acquire:
    input:
        training=f"{ACTIVE_DIR}/{{r}}/training.h5",
        surrogate=f"{ACTIVE_DIR}/{{r}}/surrogate.h5",
        particles=f"{ACTIVE_DIR}/{{r}}/particles.h5",
        previous=lambda wc: [_acquire_path(int(wc.r) - 1)] if int(wc.r) > 0 else [],
    output:
        f"{ACTIVE_DIR}/{{r}}/acquire.json",
    params:
        active=study.config["design"]["active"],
        parameters=study.config["parameters"],
        round=lambda wc: int(wc.r),
    benchmark:
        f"{R}/benchmarks/acquire/{{r}}.tsv"
    log:
        f"{R}/logs/active/{{r}}/acquire.log",
    threads: 1
    script:
        "../../scripts/acquire.py"
