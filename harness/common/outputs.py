"""Output paths of the ``rt2`` commands: checked before the work starts, written whole or not at all.

Every command that writes a file or a folder

* calls :func:`check_output_file` / :func:`check_output_dir` for each output **before** it computes
  anything, so a typo, a file where a folder is wanted, a folder that cannot be created or written,
  or a full disk is reported at once, not after an hour of work;
* writes each result with :func:`atomic_write_text` / :func:`atomic_write_json` /
  :func:`atomic_write_bytes` or inside :func:`atomic_path` (for writers that want a path:
  ``np.savez``, ``savefig``): the data go to a temporary file next to the target, which is renamed
  into place only when complete. A failure while writing (disk full, file-size limit, I/O error)
  removes the temporary file, leaves any previous file untouched, and raises :class:`OutputError`
  (a ``ValueError``: the command line prints it as one line and exits 2).

Running as root, a folder's permission bits do not stop writes (root may write there), so the
checks probe by creating a file rather than trusting ``os.access``.
"""

from __future__ import annotations

import errno
import json
import math
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

__all__ = ["MIN_FREE_BYTES", "OutputError", "atomic_path", "atomic_write_bytes", "atomic_write_json",
           "atomic_write_text", "check_output_dir", "check_output_file", "finite_or_none"]

#: an output device with less free space than this is refused before the work starts
MIN_FREE_BYTES = 1 << 20


class OutputError(ValueError):
    """An output that cannot be written; the message names the option and the path."""


def _reason(exc: OSError) -> str:
    if exc.errno == errno.ENOSPC:
        return "no space left on the device"
    if exc.errno == errno.EFBIG:
        return "file too large (a file-size limit of this process or the file system)"
    if exc.errno == errno.EROFS:
        return "read-only file system"
    return exc.strerror or str(exc)


def _probe_dir(folder: Path, flag: str, shown: str) -> None:
    """Create and remove a file in ``folder``, and look at its free space."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".rt2-probe-", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"{flag} {shown}: cannot write in folder {str(folder)!r}: {_reason(exc)}") from None
    try:
        st = os.statvfs(folder)
    except OSError:
        return
    free = st.f_bavail * st.f_frsize
    if free < MIN_FREE_BYTES:
        raise OutputError(f"{flag} {shown}: no space left on the device holding {str(folder)!r} "
                          f"({free} bytes free)")


def _make_dir(folder: Path, flag: str, shown: str) -> None:
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{flag} {shown}: {str(folder)!r} exists and is a file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError(f"{flag} {shown}: a part of {str(folder)!r} exists and is a file, not a folder") from None
    except OSError as exc:
        raise OutputError(f"{flag} {shown}: cannot create folder {str(folder)!r}: {_reason(exc)}") from None


def check_output_dir(path, flag: str = "--out") -> Path:
    """Create the output folder ``path`` (and its parents) and check it can be written; returns it."""
    path = Path(path)
    shown = repr(str(path))
    _make_dir(path, flag, shown)
    _probe_dir(path, flag, shown)
    return path


def check_output_file(path, flag: str = "--json", *, overwrite: bool = True, suffix: str | None = None):
    """Check that the file ``path`` can be written (its folder is created); returns it (None passes).

    overwrite : False refuses an existing file
    suffix : the file's required ending (e.g. ``".npz"``: weights files), checked before anything is made
    """
    if path is None:
        return None
    path = Path(path)
    shown = repr(str(path))
    if str(path) in ("", "."):
        raise OutputError(f"{flag} must name a file, got {shown}")
    if suffix is not None and path.suffix != suffix:
        raise OutputError(f"{flag} must end in {suffix}, got {shown}")
    if path.is_dir():
        raise OutputError(f"{flag} {shown} is a folder; give a file name")
    if path.exists() and not overwrite:
        raise OutputError(f"{flag} {shown} exists; choose another name (or pass --overwrite where offered)")
    _make_dir(path.parent, flag, shown)
    _probe_dir(path.parent, flag, shown)
    return path


def _umask() -> int:
    """The process's umask, read without changing it (Linux ``/proc/self/status``; elsewhere set and restored)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path, flag: str = "output"):
    """Yield a temporary path next to ``path``; on success it is renamed to ``path``, on any error removed.
    The file gets the permissions a plain ``open(path, "w")`` would give (0666 less the umask).

    An ``OSError`` inside the block becomes :class:`OutputError` naming ``flag`` and ``path``.
    The temporary name keeps the suffix (``.npz``, ``.png``), which some writers look at.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.tmp-", suffix=path.suffix, dir=path.parent)
        try:
            os.fchmod(fd, 0o666 & ~_umask())  # mkstemp makes it 0600: give it the mode open() would have
        finally:
            os.close(fd)
    except OSError as exc:
        raise OutputError(f"{flag} {str(path)!r}: cannot write: {_reason(exc)} (nothing written)") from None
    tmp = Path(tmp)
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"{flag} {str(path)!r}: cannot write: {_reason(exc)} (nothing written)") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path, data: bytes, flag: str = "output") -> Path:
    """Write ``data`` to ``path`` whole or not at all (see the module docstring); returns ``path``."""
    with atomic_path(path, flag) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    return Path(path)


def atomic_write_text(path, text: str, flag: str = "output") -> Path:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all; returns ``path``."""
    return atomic_write_bytes(path, text.encode("utf-8"), flag)


def atomic_write_json(path, obj, flag: str = "--json", *, indent=1, **kwargs) -> Path:
    """``json.dumps(obj)`` plus a newline to ``path``, whole or not at all; returns ``path``."""
    return atomic_write_text(path, json.dumps(obj, indent=indent, **kwargs) + "\n", flag)


def finite_or_none(x):
    """``x`` as a float for JSON, or None where it is None or not finite (JSON has no NaN)."""
    return None if x is None or not math.isfinite(float(x)) else float(x)
