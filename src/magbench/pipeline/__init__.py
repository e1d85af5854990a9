"""The ``calibrate`` pipeline: one user's recording in, one correction (or the reasons) out.

The steps, in order, and the module of each: read (:mod:`magbench.sources.recordings`,
:mod:`magbench.sources.logs`) -> screen, fit, choose, gate -> export -> picture. The benchmark
studies (:mod:`magbench.studies`) import this package to measure it; it imports only the engine
and the layers beneath it, and never parses the command line, draws, or prints
(:mod:`magbench.cli.calibrate` is the adapter that does).
"""
