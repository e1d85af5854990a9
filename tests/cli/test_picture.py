"""calibrate's picture process: the same file as drawn in-process, stopped when unused."""

from __future__ import annotations

import numpy as np

from magbench.cli.picture import PictureWorker, draw_picture
from magbench.core.geometry import fibonacci_sphere


def job(path, **change) -> dict:
    m = fibonacci_sphere(300)
    kwargs = {"before": 1.2 * m + 0.3, "after": m, "title": "test", "inliers": np.ones(300, bool),
              "directions": m, "gap_centre": np.array([0.0, 0.0, 1.0]), "gap_deg": 20.0}
    return {"path": path, "dpi": 40, "kwargs": {**kwargs, **change}}


def test_the_worker_writes_the_same_file_as_drawing_here(tmp_path):
    here = draw_picture(job(tmp_path / "here.png"))
    worker = PictureWorker.start()
    assert worker is not None
    try:
        assert worker.send(job(tmp_path / "worker.png"))
        assert worker.wait() == ""
    finally:
        worker.close()
    assert (tmp_path / "worker.png").read_bytes() == here.read_bytes()


def test_a_failing_worker_says_why_in_one_line(tmp_path):
    worker = PictureWorker.start()
    try:
        assert worker.send(job(tmp_path / "bad.png", gap_deg=None, bogus=1))
        problem = worker.wait()
    finally:
        worker.close()
    assert problem.startswith("the picture process failed (") and "\n" not in problem
    assert "bogus" in problem and not (tmp_path / "bad.png").exists()


def test_an_unused_worker_is_stopped_by_close():
    worker = PictureWorker.start()
    worker.close()
    assert worker._proc.poll() is not None


def test_calibrate_draws_the_picture_itself_when_the_worker_fails(tmp_path, monkeypatch,
                                                                  capsys):
    import pandas as pd

    from magbench.cli import main

    start = PictureWorker.start

    def broken(cls):
        worker = start()
        worker._proc.kill()                 # gone before it is given the picture
        worker._proc.wait()
        return worker

    monkeypatch.setattr(PictureWorker, "start", classmethod(broken))
    y = fibonacci_sphere(200) @ np.diag([500.0, 450.0, 600.0]) + [900.0, -300.0, 100.0]
    pd.DataFrame(y, columns=["mx", "my", "mz"]).to_csv(tmp_path / "rec.csv", index=False)
    assert main(["calibrate", f"file={tmp_path / 'rec.csv'}", "method=fang", "bootstrap=0",
                 f"out={tmp_path / 'o'}"]) == 0
    assert (tmp_path / "o" / "calibration.png").stat().st_size > 20_000
