"""How jobs run: the per-run job server that forks per-point and per-round jobs from
a warm process (:mod:`.jobserver`) and the console's progress line
(:mod:`.progress`). Process-group helpers shared with the command forward model are
in :mod:`bayescalib._process`."""
