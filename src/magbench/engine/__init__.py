"""The engine: the one trial loop (:mod:`~magbench.engine.trial`) and the one sweep runner
(:mod:`~magbench.engine.sweep`) under every study, with plugins and the run record."""
