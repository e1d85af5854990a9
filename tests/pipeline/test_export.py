"""The export step (:mod:`magbench.pipeline.export`); the files it writes are checked through the
command in tests/cli/test_calibrate.py."""

from __future__ import annotations

from magbench.pipeline.export import _export_rotation


def test_an_ardupilot_logs_rotation_is_relative_so_it_is_not_written():
    found = {"id": 6, "name": "ROTATION_YAW_270"}
    assert _export_rotation({"file": "a.ulg", "mounting_rotation": found}) == (6, "")
    assert _export_rotation({"file": "a.csv", "mounting_rotation": found}) == (6, "")
    rotation, line = _export_rotation({"file": "a.BIN", "mounting_rotation": found})
    assert rotation is None and line.startswith("mounting: set COMPASS_ORIENT = 6 "
                                                 "(ROTATION_YAW_270) if it is 0")
    assert "comes on top of its current value" in line
    assert _export_rotation({"file": "a.csv", "mounting_rotation": {"id": None}}) == (None, "")
    assert _export_rotation({"file": "a.csv"}) == (None, "")
