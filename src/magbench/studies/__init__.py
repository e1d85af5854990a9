"""Studies: what each experiment runs (work units and their rows) and its statistics.

Every study runs on :mod:`magbench.engine`; none parses the command line, draws a figure or
writes report text. ``calibrate`` itself is :mod:`magbench.pipeline`, the layer beneath: the
studies that measure it (real recordings, generalisation, heading) import it from there.
"""
