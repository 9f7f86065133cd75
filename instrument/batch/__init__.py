"""Many runs at once: ``scatterlab batch`` and the parameter sweeps, on Dask (ADR 0070).

* :mod:`.analyses` — the four analyses (fit, reconstruct, locate, spheres) as functions of a
  run path and plain options: each runs its pipeline as the single-run command does (the
  pipeline writes ``results.h5``) and returns a plain-data summary row;
* :mod:`.select` — which runs: paths, globs, a catalog query;
* :mod:`.task` — one analysis of one run as a batch task: the run's lock, "already done",
  failures caught and reported, the summary row kept next to the results file;
* :mod:`.summary` — the summary table (CSV and HTML);
* :mod:`.cluster` — the Dask side (a local cluster or an existing scheduler, the batch on
  it, ordered maps for sweeps). It is the only module that imports Dask, and nothing
  imports it at start-up, so the rest works (and ``scatterlab --help`` stays fast)
  without the ``cluster`` extra.
"""
