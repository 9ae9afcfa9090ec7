"""Forward models: design-point values in, deformed interface out. The protocol and
the one way to solve a point (:mod:`.forward`), the analytic stand-in used by tests
and benchmarks (:mod:`.analytic`) and the NGSolve FSI model (:mod:`.fsi`)."""
