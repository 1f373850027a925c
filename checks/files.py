"""Checked reading of the files we parse (rigs, configurations, annotations, models).

A file handed to rt2 may be damaged or hostile: a YAML alias bomb (449 bytes that expand to
gigabytes), a 200 MB "rig", a link to ``/dev/zero``, random bytes named ``.npz``, a zip bomb.
Every loader reads through these functions, which

* read at most ``max_bytes`` (the file is never read whole when it is too big, whatever it is);
* refuse YAML aliases (``*name``): our files never need them and they are how a bomb expands;
* refuse npz members that would decompress beyond ``max_bytes`` or hold pickled objects;
* raise ``ValueError`` naming the file (and what was wrong) in one line, never a deep traceback.

The lowest layer of rt2 (``checks/`` imports nothing else of ours), so every package reads its files
through these functions: rigs, detector models, ProMPs, ball parameters, play profiles and the robot
configuration (docs/architecture.md).
"""

from __future__ import annotations

import os
import reprlib
import stat
import zipfile
from pathlib import Path

import numpy as np
import yaml

__all__ = ["MAX_CONFIG_BYTES", "MAX_DATA_BYTES", "MAX_MODEL_BYTES", "NoAliasSafeLoader", "load_npz_checked",
           "load_yaml_checked", "parse_yaml_checked", "read_bytes_capped", "read_text_capped", "short", "yaml_problem"]

#: rig, robot, ball-parameter and play-profile files (a 50-camera rig is ~50 kB)
MAX_CONFIG_BYTES = 4 << 20
#: annotation files (COCO JSON of a large data set)
MAX_DATA_BYTES = 512 << 20
#: model files (.npz), compressed and uncompressed
MAX_MODEL_BYTES = 256 << 20


_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict, _REPR.maxset = 3, 8, 8, 8, 8
_REPR.maxstring, _REPR.maxother, _REPR.maxlong = 80, 80, 40


def short(value, limit: int = 80) -> str:
    """A short text for ``value`` in an error message, built without ever expanding it whole
    (a YAML alias bomb's value has billions of items; its ``repr`` would never finish)."""
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape} and dtype {value.dtype}"
    text = _REPR.repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _mb(n: int) -> str:
    return f"{n / (1 << 20):g} MiB"


def read_bytes_capped(path, max_bytes: int, what: str = "file") -> bytes:
    """The bytes of ``path``, refusing (``ValueError``) a file larger than ``max_bytes``.

    Reads at most ``max_bytes + 1`` bytes, so a device or a growing file is never read whole.
    A missing, unreadable or too large file and a directory all raise ``ValueError`` naming it.
    """
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise ValueError(f"cannot read {what} {str(path)!r}: {exc.strerror or exc}") from None
    if stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode):  # opening a pipe would wait for a writer forever
        raise ValueError(f"{what} {str(path)!r} is a pipe or socket, not a file")
    try:
        with open(path, "rb") as f:
            st = os.fstat(f.fileno())
            if stat.S_ISDIR(st.st_mode):
                raise ValueError(f"{what} {str(path)!r} is a directory, not a file")
            if stat.S_ISREG(st.st_mode) and st.st_size > max_bytes:
                raise ValueError(f"{what} {str(path)!r} is {_mb(st.st_size)}, more than the {_mb(max_bytes)} "
                                 f"a {what} may have; refusing to read it")
            data = f.read(max_bytes + 1)
    except IsADirectoryError:
        raise ValueError(f"{what} {str(path)!r} is a directory, not a file") from None
    except OSError as exc:
        raise ValueError(f"cannot read {what} {str(path)!r}: {exc.strerror or exc}") from None
    if len(data) > max_bytes:
        raise ValueError(f"{what} {str(path)!r} is longer than the {_mb(max_bytes)} a {what} may have "
                         "(not a regular file?); refusing to read it")
    return data


def read_text_capped(path, max_bytes: int, what: str = "file") -> str:
    """:func:`read_bytes_capped` decoded as UTF-8; a binary file raises ``ValueError`` naming it."""
    data = read_bytes_capped(path, max_bytes, what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{what} {str(path)!r} is not a UTF-8 text file (byte {exc.start} is "
                         f"{data[exc.start:exc.start + 1]!r}); is it a binary file?") from None


class NoAliasSafeLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses aliases (``*name``), so a document cannot expand beyond its text."""

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(None, None, f"YAML aliases (*{event.anchor}) are not allowed in rt2 files",
                                              event.start_mark)
        return super().compose_node(parent, index)


def parse_yaml_checked(text: str, source: str, loader=NoAliasSafeLoader):
    """Parse YAML ``text`` (from ``source``, for messages) with an alias-refusing safe ``loader``."""
    if not (isinstance(loader, type) and issubclass(loader, NoAliasSafeLoader)):
        raise ValueError(f"loader must be a subclass of NoAliasSafeLoader, got {short(loader)}")
    try:
        return yaml.load(text, Loader=loader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as exc:
        raise ValueError(f"{source}: not valid YAML: {yaml_problem(exc)}") from None
    except RecursionError:
        raise ValueError(f"{source}: YAML nested too deeply") from None


def yaml_problem(exc: yaml.YAMLError) -> str:
    """One short line for a YAML error: what and where (line, column), without quoting the document."""
    problem = getattr(exc, "problem", None) or getattr(exc, "context", None) or str(exc).splitlines()[0]
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
    return f"{problem[:200]}{where}"


def load_yaml_checked(path, what: str = "file", *, max_bytes: int = MAX_CONFIG_BYTES, loader=NoAliasSafeLoader):
    """Read (capped, UTF-8) and parse (no aliases) the YAML file ``path``; ``ValueError`` naming it otherwise."""
    return parse_yaml_checked(read_text_capped(path, max_bytes, what), str(path), loader)


def load_npz_checked(path, what: str = "model file", *, max_bytes: int = MAX_MODEL_BYTES) -> dict:
    """The arrays of the ``.npz`` file ``path`` as {name: array}, checked before anything is decompressed.

    Refuses (``ValueError`` naming the file) a file that is not a zip archive, a file or member
    larger than ``max_bytes`` (compressed or uncompressed: zip bombs), and pickled objects.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{what} {str(path)!r} does not exist")
    try:
        with open(path, "rb") as f:
            head = f.read(4)
            size = os.fstat(f.fileno()).st_size
    except IsADirectoryError:
        raise ValueError(f"{what} {str(path)!r} is a directory, not a file") from None
    except OSError as exc:
        raise ValueError(f"cannot read {what} {str(path)!r}: {exc.strerror or exc}") from None
    if head != b"PK\x03\x04":
        got = "is empty" if not head else f"starts with {head!r}"
        raise ValueError(f"{what} {str(path)!r} is not a readable .npz archive (not a zip file: it {got})")
    if size > max_bytes:
        raise ValueError(f"{what} {str(path)!r} is {_mb(size)}, more than the {_mb(max_bytes)} allowed; refusing to read it")
    try:
        with zipfile.ZipFile(path) as zf:
            total = sum(i.file_size for i in zf.infolist())
        if total > max_bytes:
            raise ValueError(f"{what} {str(path)!r} would decompress to {_mb(total)}, more than the "
                             f"{_mb(max_bytes)} allowed; refusing to read it")
        with np.load(path, allow_pickle=False) as npz:
            out = {}
            for k in npz.files:
                try:
                    out[k] = npz[k]
                except ValueError as exc:
                    if "pickle" in str(exc):
                        raise ValueError(f"{what} {str(path)!r}: field {k!r} holds pickled Python objects, which rt2 "
                                         "never loads (a model holds only numeric and text arrays)") from None
                    raise
            return out
    except ValueError as exc:
        if str(path) in str(exc):
            raise
        raise ValueError(f"{what} {str(path)!r} is not a readable .npz archive ({type(exc).__name__}: {exc})") from None
    except (zipfile.BadZipFile, OSError, EOFError, KeyError, zipfile.LargeZipFile) as exc:
        raise ValueError(f"{what} {str(path)!r} is not a readable .npz archive ({type(exc).__name__}: {exc})") from None
