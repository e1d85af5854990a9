"""``calibrate``'s picture, drawn by a second process while the first one fits.

Drawing ``calibration.png`` costs about half a second, most of it importing matplotlib and
laying out seven axes, which is as long as reading, fitting and choosing on a 10 000-sample
recording. :func:`magbench.cli.main.main` therefore starts :class:`PictureWorker` before it
loads anything else: a fresh interpreter (``python -m magbench.cli.picture``) that imports the
figure code, builds the picture's axes (:func:`~magbench.figures.calibration.picture_layout`)
and waits; ``calibrate`` sends it the arrays of
:func:`magbench.figures.calibration.calibration_picture` once the calibration is chosen, and waits
for the file before it reports. On two cores the picture then costs only its drawing.

The worker is only a speed-up: if it cannot start, dies or fails, ``calibrate`` draws the
picture itself and the output is the same file. A worker never given a picture (a bad
argument, a refused recording) is stopped when the command ends; one whose parent dies sees
the end of its input and exits.
"""

from __future__ import annotations

import gc
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from magbench.figures.calibration import PictureLayout

__all__ = ["PictureWorker", "draw_picture"]

#: Longest wait for the worker's picture before drawing it here instead (seconds).
WAIT_S = 120.0


def draw_picture(job: dict, layout: PictureLayout | None = None) -> Path:
    """Draw and save one picture: ``job`` holds ``path``, ``dpi``, optionally the PNG
    ``compress_level``, and the keyword arguments ``kwargs`` of
    :func:`~magbench.figures.calibration.calibration_picture`, drawn on ``layout`` if given
    (the same pixels). Returns the path."""
    from magbench.figures.calibration import calibration_picture
    from magbench.figures.style import save_figure

    return save_figure(calibration_picture(**job["kwargs"], layout=layout), job["path"],
                       dpi=job["dpi"], compress_level=job.get("compress_level"))


class PictureWorker:
    """A process that draws one picture (module notes)."""

    def __init__(self, proc: subprocess.Popen, errors) -> None:
        self._proc, self._errors, self._sent = proc, errors, False

    @classmethod
    def start(cls) -> PictureWorker | None:
        """Start the worker; None if no process can be started (the caller draws itself)."""
        package_root = str(Path(__file__).resolve().parents[2])
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            p for p in (package_root, os.environ.get("PYTHONPATH")) if p)}
        errors = tempfile.TemporaryFile()
        try:
            proc = subprocess.Popen([sys.executable, "-m", "magbench.cli.picture"],
                                    stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                    stderr=errors, env=env)
        except OSError:
            errors.close()
            return None
        return cls(proc, errors)

    def send(self, job: dict) -> bool:
        """Hand the worker its picture (:func:`draw_picture`'s ``job``); False if it is gone."""
        try:
            pickle.dump(job, self._proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self._proc.stdin.close()
        except (BrokenPipeError, OSError, ValueError):
            return False
        self._sent = True
        return True

    def wait(self) -> str:
        """Wait for the picture: "" when it is written, else why not (one line)."""
        try:
            code = self._proc.wait(timeout=WAIT_S)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
            return f"the picture process took more than {WAIT_S:.0f} s"
        if code == 0:
            return ""
        self._errors.seek(0)
        lines = self._errors.read().decode(errors="replace").strip().splitlines()
        return f"the picture process failed ({lines[-1] if lines else f'exit {code}'})"

    def close(self) -> None:
        """Stop the worker if it never got a picture; release its files."""
        if not self._sent and self._proc.poll() is None:
            self._proc.kill()
        self._proc.wait()
        if self._proc.stdin and not self._proc.stdin.closed:
            self._proc.stdin.close()
        self._errors.close()


def _serve() -> int:
    """The worker: import the figure code and build the picture's axes, then draw the one
    picture read from stdin."""
    # A short life that draws one picture: no cyclic collection, which would walk
    # matplotlib's objects again and again (a tenth of the import time).
    gc.disable()
    # The slow import and the axes (a quarter of the drawing), while the parent fits.
    from magbench.figures.calibration import picture_layout

    layout = picture_layout()
    try:
        job = pickle.load(sys.stdin.buffer)
    except EOFError:
        return 0          # the command ended without a picture to draw
    draw_picture(job, layout)
    # The parent waits for this process to end: skip the interpreter's tear-down of matplotlib
    # (the picture is written and closed; nothing else is buffered but stderr).
    sys.stderr.flush()
    os._exit(0)


if __name__ == "__main__":
    raise SystemExit(_serve())
