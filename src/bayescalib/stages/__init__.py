"""Pipeline stages: one module per Snakemake rule, the stage's function named as the rule.

How a job reaches its stage: most rules run through the run's job server, whose table
:data:`bayescalib.execution.jobserver.STAGES` names each stage's function
(``module:function``); the rule's command sends a JSON job document (the rule's named
inputs, outputs and params, :func:`bayescalib.execution.jobserver.job_document`) and the
function is called with its values as keyword arguments, its log set up first. The rules
``observe``, ``convergence``, ``ground_truth``, ``base_state`` and ``diagnose`` run a
script of ``scripts/``, which sets up the log, unpacks ``snakemake.input/params/output``
and calls one function (for ``observe`` and ``convergence``, the stage's function here).
Either way every stage can be run and tested without Snakemake: it reads its
inputs, does its one job with the library, and writes its outputs atomically, so that
an interrupted run never leaves a half-written file that a later run would trust.

This package holds no code and imports nothing: import each function from its module.

Stages (the rule -> its module, and what its function does):

``observe``          :mod:`~bayescalib.stages.observe`: the observation set (synthetic
                     from the ground-truth solve, or read from files)
``solve``            :mod:`~bayescalib.stages.jobs`: one design point's forward solve
                     (also ``predictive_solve``: a posterior draw's)
``discrepancy``      :mod:`~bayescalib.stages.discrepancy`: D and the log-likelihood of
                     one design point for one measure
``gather``           :mod:`~bayescalib.stages.gather`: the training table of all design
                     points of a measure (also ``gather_round``)
``train_surrogate``  :mod:`~bayescalib.stages.surrogate`: the GP surrogate of the
                     log-likelihood, or the output emulator (also ``train_round``)
``convergence``      :mod:`~bayescalib.stages.convergence`: the GP's error over n_train
                     on held-out Sobol points
``smc``              :mod:`~bayescalib.stages.smc`: SMC particles on the surrogate (also
                     ``smc_round``)
``acquire``          :mod:`~bayescalib.stages.acquire`: the end of an active round:
                     checks, stop rule and the next batch
``marginalize``      :mod:`~bayescalib.stages.marginalize`: the posterior's summaries
                     and its ArviZ export
``posterior_check``  :mod:`~bayescalib.stages.posterior_check`: the final posterior
                     checked with real solves by importance sampling
``summary``          :mod:`~bayescalib.stages.summary`: summary.json (its job function
                     in :mod:`~bayescalib.stages.jobs`), the run line, the report's
                     front page
``fig_*``            :mod:`~bayescalib.stages.figures`: the figures (also
                     ``posterior_mean_solve``)

Shared by the stages: :mod:`~bayescalib.stages.errors` (``PipelineError``, a stage
that cannot proceed), :mod:`~bayescalib.stages.files` (writing JSON, the one reader of
every stage file, setting aside an unreadable one, reusing an earlier job's output),
:mod:`~bayescalib.stages.logs` (a job's log), :mod:`~bayescalib.stages.chain` (the rounds
of a calibration in files, run in-process by the diagnosis) and
:mod:`~bayescalib.stages.verdict` (a finished run's verdict).
"""
