"""Inference on the log-likelihood of the discrepancy: parameters and priors, the
Sobol design, the Gaussian likelihood, the GP surrogate, SMC with adaptive tempering,
weighted particles, posterior summaries, the active design and its rounds."""
