"""Model-form diagnosis: check the calibrated model against the data, locate the
mismatch on the interface, attribute it to candidate physics, calibrate the extended
model and show the improvement (issue: model-form diagnosis).

Modules: :mod:`~bayescalib.diagnosis.residuals` (posterior predictive check, bands,
located intervals), :mod:`~bayescalib.diagnosis.attribution` (signatures, score
tests, sparse selection), :mod:`~bayescalib.diagnosis.extended` (calibration of the
extended model by the study's active-design chain, :mod:`bayescalib.stages.chain`, and Bayes
factors), :mod:`~bayescalib.diagnosis.stage`
(the pipeline stage writing ``diagnosis.json``), :mod:`~bayescalib.diagnosis.detection`
(detection limits: noise trials of the linearized diagnosis on real solves,
``benchmarks/detection_limits.py``).
"""
