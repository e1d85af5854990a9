"""Figures: one style, one palette (a fixed colour and marker per method), one atomic save.

Every figure is drawn from CSV files (never from a running study) and saved as a PNG beside the
CSV of the numbers it plots.
"""
