"""The machinery the estimation runs on, apart from the algorithm: worker processes (how they
are started, what they inherit, when they die) and their memory. Nothing here imports the
algorithm's modules (:mod:`multi_map_merge.core`); :mod:`core.workers` uses it."""
