"""``calibrate``'s out folder, written as one.

A calibration is several files (``calibration.json``, ``calibration.h``, the firmware files,
``ranking.csv``, ``calibration.png``) that must belong to one run: a firmware file beside
another recording's JSON would flash another sensor's offsets. So :func:`hold`:

1. takes the operating system's lock on a file beside ``out`` (``.NAME.lock`` in its parent,
   not inside it, so that it does not travel with the swapped folder), refusing a second
   writer in one line; the lock is held from the overwrite check to the last write, and its
   file is removed while still held, so nothing is left behind
   (:func:`magbench.core.files.exclusive_lock`, ``filelock`` underneath);
2. checks the overwrite rule *under the lock* (``out`` holding a calibration needs
   ``overwrite=true``), and refuses an ``out`` holding files ``calibrate`` does not write
   (the whole folder is replaced);
3. hands out a fresh staging folder beside ``out`` (``.NAME.new-PID``) for every file;
4. on :meth:`Staging.commit` writes ``manifest.json`` last (every file with its SHA-256), then
   puts the staging folder in place in one step: a plain rename when ``out`` does not exist,
   else an atomic exchange of the two folders (Linux ``renameat2(RENAME_EXCHANGE)``); where
   that call does not exist, two renames, with the old folder kept as ``.NAME.old-PID`` until
   the new one is in place and restored by the next :func:`hold` if a kill came between them.

So after a kill at any moment ``out`` holds the complete old result or the complete new one;
leftover staging folders beside it are removed by the next run. ``apply`` checks
``manifest.json`` (:func:`check_manifest`) when the calibration sits beside one.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import json
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from magbench.cli.config import UsageError, writable_folder
from magbench.core.files import LockHeld, exclusive_lock, file_sha256, write_text_atomic

__all__ = ["CARRIED", "MANIFEST", "OUTPUTS", "Staging", "check_manifest", "hold"]

MANIFEST = "manifest.json"
#: Every file ``calibrate`` may write into its folder (an ``out`` holding others is refused).
OUTPUTS = ("calibration.json", "calibration.h", "ardupilot.param", "px4.params", "inav.txt",
           "betaflight.txt", "ranking.csv", "calibration.png", MANIFEST)
#: The recording ``capture`` saves into the folder it then calibrates into: carried into the
#: new folder (and its manifest), so the calibration stays beside the samples it came from.
CARRIED = ("capture.csv", "capture.json")
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


class Staging:
    """The fresh folder a run writes into; :meth:`commit` puts it in place as ``out``."""

    def __init__(self, out: Path, path: Path) -> None:
        self.out, self.path, self.committed = out, path, False

    def commit(self) -> None:
        """Write the manifest last, then swap the staging folder into ``out`` (module notes)."""
        files = sorted(p.name for p in self.path.iterdir() if p.is_file()
                       and p.name != MANIFEST and not p.name.startswith("."))
        manifest = {"format": "magbench-calibration-folder", "files": {
            name: file_sha256(self.path / name) for name in files}}
        write_text_atomic(json.dumps(manifest, indent=2) + "\n", self.path / MANIFEST)
        _fsync_folder(self.path)
        if not self.out.exists():
            os.rename(self.path, self.out)
        elif not _exchange(self.path, self.out):
            old = self.out.with_name(f".{self.out.name}.old-{os.getpid()}")
            os.rename(self.out, old)
            os.rename(self.path, self.out)
            self.path = old
        _fsync_folder(self.out.parent)
        self.committed = True
        # ``path`` now holds the previous result (or nothing): it is removed by hold().


def _fsync_folder(path: Path) -> None:
    """Flush a folder's entries to disk (a rename is durable only then); best effort."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two folders atomically with Linux's renameat2; False where it is unavailable."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        call = libc.renameat2
    except (OSError, AttributeError):
        return False
    call.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                     ctypes.c_uint]
    if call(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (22, 38, 95):         # EINVAL, ENOSYS, EOPNOTSUPP: file system without it
        return False
    raise OSError(err, os.strerror(err), str(b))


def _recover(out: Path) -> None:
    """Undo what a killed run left beside ``out`` (module notes): an old folder moved aside
    while the new one was not yet in place is put back; staging folders are removed."""
    leftovers = sorted(out.parent.glob(f".{out.name}.old-*")) + \
        sorted(out.parent.glob(f".{out.name}.new-*"))
    for path in leftovers:
        if path.name.startswith(f".{out.name}.old-") and not out.exists():
            os.rename(path, out)
            continue
        shutil.rmtree(path, ignore_errors=True)


def _foreign(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if p.name not in OUTPUTS + CARRIED)


@contextlib.contextmanager
def hold(out: Path | str, overwrite: bool) -> Iterator[Staging]:
    """Lock ``out``, check it may be written and yield a :class:`Staging` folder; the staging
    folder is removed at the end unless committed (module notes).

    Raises
    ------
    UsageError
        Another run holds ``out``; ``out`` holds a calibration and ``overwrite`` is false;
        ``out`` holds files ``calibrate`` does not write; or the folder beside it cannot be
        written. One line each.
    """
    out = Path(out).expanduser()
    if out.exists() and not out.is_dir():
        raise UsageError(f"out={out} is a file; expected a folder")
    parent = writable_folder(out.parent if str(out.parent) else Path("."), "out")
    out = parent / out.name
    lock = contextlib.ExitStack()
    try:
        lock.enter_context(exclusive_lock(parent / f".{out.name}.lock"))
    except LockHeld:
        raise UsageError(f"out={out} is being written by another magbench calibrate; wait "
                         "for it to finish or choose another out=") from None
    staging = None
    try:
        _recover(out)
        if out.exists():
            if not overwrite and (out / "calibration.json").exists():
                raise UsageError(f"out={out} already holds a calibration (calibration.json); "
                                 "pass overwrite=true to replace it, or choose another out=")
            foreign = _foreign(out)
            if foreign:
                shown = ", ".join(foreign[:3]) + (" ..." if len(foreign) > 3 else "")
                raise UsageError(f"out={out} holds files calibrate does not write ({shown}); "
                                 "the folder is replaced as a whole: choose an empty or new "
                                 "folder")
        staging = Staging(out, parent / f".{out.name}.new-{os.getpid()}")
        shutil.rmtree(staging.path, ignore_errors=True)
        staging.path.mkdir()
        for name in CARRIED:
            if (out / name).is_file():
                shutil.copy2(out / name, staging.path / name)
        yield staging
    finally:
        if staging is not None:
            shutil.rmtree(staging.path, ignore_errors=True)
        lock.close()            # the lock file is removed while still held


def check_manifest(folder: Path) -> str:
    """"" when ``folder/manifest.json`` lists every file beside it with its checksum, else
    why not (one line); "" too for a folder without a manifest (a calibration.json copied
    elsewhere, or written before manifests)."""
    path = folder / MANIFEST
    if not path.exists():
        return ""
    try:
        files = json.loads(path.read_text())["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return f"{path} is not a magbench manifest"
    for name, digest in files.items():
        if not isinstance(name, str) or "/" in name or name.startswith("."):
            return f"{path} names an unexpected file {name!r}"
        if not (folder / name).is_file() or file_sha256(folder / name) != digest:
            return (f"{folder / name} does not match {MANIFEST} (the folder was changed or "
                    "mixed with another run's files)")
    return ""
