"""The ``calibrate`` pipeline: one user's recording in, one correction (or the reasons) out.

The steps, in order, and where each is:

1. *read*: :func:`magbench.pipeline.reading.read_recording` over the readers of
   :mod:`magbench.sources.recordings` and :mod:`magbench.sources.logs` (a CSV or a flight
   log, the columns, the unit, the coverage); :mod:`magbench.pipeline.alignment` removes the
   magnetometer's lag against the inertial streams and checks for an offset that changes.
2. *screen*: :func:`magbench.pipeline.screening.prepare` (thinning by direction, the outlier
   screen of :func:`magbench.core.robust.screen`, the coverage) and, after the choice,
   :func:`~magbench.pipeline.screening.retrim` around the chosen fit.
3. *fit*: every candidate on all samples and on interleaved time-block folds, in rounds
   (:func:`magbench.pipeline.rounds.fit_round`, :mod:`magbench.pipeline.holdout`), each
   fit by :func:`magbench.pipeline.fitting.fit_recording`.
4. *choose*: :mod:`magbench.pipeline.choice` (held-out ranking, the tie, the simplest model),
   with the direction veto of :mod:`magbench.pipeline.alignment`.
5. *gate*: :func:`magbench.pipeline.gate.judge` (verdict, intervals, PASS / WARN / FAIL by
   :mod:`magbench.core.verdict`; the block-bootstrap intervals of
   :mod:`magbench.pipeline.bootstrap`) and the field strength against the Earth's in
   :func:`magbench.pipeline.decision.decide`, which runs steps 1-5 on one recording.
6. *export*: :mod:`magbench.pipeline.export` (``calibration.json``, ``calibration.h``, the
   firmware files), with the mounting rotation and the time-varying terms of
   :mod:`magbench.pipeline.flight`.
7. *picture*: :mod:`magbench.pipeline.picture` (the job that ``calibration.png`` is drawn from).

:func:`magbench.pipeline.calibration.calibrate_recording` runs steps 2-5, one module a step,
into a :class:`magbench.pipeline.result.CalibrationResult`.
:func:`magbench.pipeline.auto.calibrate_auto` is the same decision for a program (arrays in,
no file). The benchmark studies (:mod:`magbench.studies`) import this package to measure it;
it imports only the engine and the layers beneath it, and never parses the command line,
draws or prints: :mod:`magbench.cli.calibrate` is the adapter that does.
"""
