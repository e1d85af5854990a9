"""Core: the model and its result type, input validation, geometry, rotations, metrics and
the Cramer-Rao bound. Imports nothing else of magbench."""
