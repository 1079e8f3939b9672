"""`ltmap batch`: many robots, sites and days replayed on a distributed engine (Dask).

- ``manifest``: the fleet manifest (FLEET.yaml) read and checked; a bad entry is one line naming
  it (``ManifestError``, exit 2);
- ``graph``: the tasks: a static plan built once per site, then per site and sweep point a chain
  of days, each resuming from the one before; the fingerprint that says a day is up to date;
- ``tasks``: what a worker runs (the replay library in a staging folder renamed into place);
- ``runner``: the engine (an embedded ``LocalCluster`` or a running scheduler's address), the
  chains submitted in order, retries, progress;
- ``summary``: ``OUT/summary.csv`` (and ``summary.png``, drawn by ``viz.fleet``) from the days'
  ``report.json``.
"""
