"""Results of slow, deterministic computations kept on disk, shared by processes and runs (``diskcache``).

The simulated lab ray-casts its static room once per camera (~1 s per VGA camera); every process that renders
the lab (``rt2 track --source sim``, its render child, each study, each test worker) did so again. Through
:func:`cached` the result is computed once per machine and read back in milliseconds afterwards.

A result is found again only for the same arguments **and the same code**: the key is a sha256 of the
computation's name, its arguments (``key_of(*args)``: bytes that name everything the result depends on), the
source of every module the computation reads (``code_of``) and numpy's version. An edited module, another numpy or
another camera is a new entry, never a stale one.

Where: ``$RT2_CACHE_DIR`` if set (``off`` or an empty value: no cache, every call computes), else
``$XDG_CACHE_HOME/rt2`` or ``~/.cache/rt2``. ``make test`` uses ``build/cache`` of the checkout, so a fresh clone's
first run starts cold. The folder is kept under ``$RT2_CACHE_MAX_MB`` megabytes (default 2048; the entries stored
first go first) and can be deleted at any time; an entry that would leave less than 2 GiB free on its disk is not
stored (a session log on the same disk matters more). A folder that cannot be created or written, or an entry that
cannot be read back (a truncated file), costs only the computation: the result is computed and returned as
without a cache, with one warning naming the folder.

``diskcache`` keeps the index in SQLite and each large value in a file of its own, written whole before it is
indexed, so processes that compute the same entry at once (two test workers) each get a whole result. A result is a
dict of arrays, stored as the bytes of an ``.npz`` archive and read back with ``allow_pickle=False``: as with model
files, rt2 never unpickles what it reads from disk, so a cache folder others can write to cannot run their code.
"""

from __future__ import annotations

import functools
import hashlib
import io
import os
import shutil
import warnings
from pathlib import Path
from types import ModuleType
from typing import Any, Callable

__all__ = ["CACHE_DIR_ENV", "CACHE_MAX_MB_ENV", "cache_location", "cached", "clear", "code_digest", "summary"]

CACHE_DIR_ENV = "RT2_CACHE_DIR"
CACHE_MAX_MB_ENV = "RT2_CACHE_MAX_MB"
_DEFAULT_MAX_MB = 2048
_OFF = ("", "off", "0", "none")
_FORMAT = b"npz-1"  #: in every key: entries of another storage format are misses, not unreadable
#: an entry is not stored where it would leave less free space than this on the cache's disk (a session log or a
#: recording on the same disk needs it more than a cache does)
MIN_FREE_AFTER_BYTES = 2 * 1024**3


def cache_location() -> Path | None:
    """The cache folder (see the module docstring), or None when it is turned off."""
    value = os.environ.get(CACHE_DIR_ENV)
    if value is not None:
        return None if value.strip().lower() in _OFF else Path(value).expanduser().absolute()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rt2"


def _max_bytes() -> int:
    value = os.environ.get(CACHE_MAX_MB_ENV, "")
    try:
        mb = float(value) if value.strip() else float(_DEFAULT_MAX_MB)
    except ValueError:
        mb = float("nan")
    if not 0 < mb < float("inf"):
        warnings.warn(f"{CACHE_MAX_MB_ENV}={value!r} is not a positive number of megabytes; using {_DEFAULT_MAX_MB}",
                      stacklevel=4)
        mb = float(_DEFAULT_MAX_MB)
    return int(mb * 1e6)


def code_digest(*modules: ModuleType | str) -> str:
    """sha256 of the source files of ``modules`` (module objects, or dotted names: found, not imported) and of numpy's
    version: what a cached result was computed by."""
    import importlib.util

    import numpy

    h = hashlib.sha256(numpy.__version__.encode())
    for module in modules:
        name = module if isinstance(module, str) else module.__name__
        try:
            spec = importlib.util.find_spec(name) if isinstance(module, str) else None
        except (ImportError, ValueError):  # a parent package that does not exist
            spec = None
        path = spec.origin if spec is not None else getattr(module, "__file__", None)
        if not path or not Path(path).is_file():
            raise ValueError(f"code_digest: module {name!r} has no source file")
        h.update(name.encode() + b"\0")
        h.update(Path(path).read_bytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=8)
def _open(location: str, max_bytes: int):
    """The ``diskcache.Cache`` at ``location`` (made if missing), or None (with one warning) where it cannot be opened
    or written."""
    try:
        Path(location).mkdir(parents=True, exist_ok=True)
        probe = Path(location) / f".probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
        return _opened(Path(location), max_bytes)
    except Exception as exc:  # noqa: BLE001 - an unusable cache costs the computation, never the command
        warnings.warn(f"the disk cache {location!r} cannot be used ({type(exc).__name__}: {exc}); computing without it",
                      stacklevel=4)
        return None


def cached(name: str, func: Callable[..., Any], *, key_of: Callable[..., bytes],
           code_of: tuple[ModuleType | str, ...]) -> Callable[..., Any]:
    """``func`` memoised on disk: the returned function gives ``func(*args)``, computed at most once per machine for
    the same ``key_of(*args)`` and the same source of ``code_of`` (every module ``func`` reads: modules or dotted
    names, the names not imported until ``func`` runs). ``name`` keeps computations apart and names them in
    warnings. ``func`` returns a dict of numpy arrays (numbers, not objects); read back, each has the same dtype,
    shape and bytes."""
    digest: str | None = None

    @functools.wraps(func)
    def call(*args):
        nonlocal digest
        location = cache_location()
        cache = None if location is None else _open(str(location), _max_bytes())
        if cache is None:
            return func(*args)
        if digest is None:
            digest = code_digest(*code_of)
        key = f"{name}-" + hashlib.sha256(_FORMAT + digest.encode() + b"\0" + key_of(*args)).hexdigest()
        try:
            data = cache.get(key, default=None)
            result = None if data is None else _from_bytes(data)
        except Exception as exc:  # noqa: BLE001 - a truncated or foreign file: drop it, compute again
            warnings.warn(f"the disk cache {str(location)!r}: its {name} entry could not be read back "
                          f"({type(exc).__name__}: {exc}); computed again", stacklevel=2)
            _forget(cache, key)
            result = None
        if result is not None:
            return result
        result = func(*args)
        data = _to_bytes(result, name)
        try:
            free = shutil.disk_usage(location).free
            if free - len(data) < MIN_FREE_AFTER_BYTES:
                warnings.warn(f"the disk cache {str(location)!r}: a {name} entry not stored, {free / 1e6:.0f} MB free on its "
                              f"disk (it keeps {MIN_FREE_AFTER_BYTES / 1024**3:g} GiB free for what matters more)", stacklevel=2)
                return result
            cache.set(key, data)
        except Exception as exc:  # noqa: BLE001 - a full disk: the result stands, uncached
            warnings.warn(f"the disk cache {str(location)!r}: could not store a {name} entry "
                          f"({type(exc).__name__}: {exc})", stacklevel=2)
        return result

    return call


def summary() -> dict:
    """What the cache holds (``rt2 cache info``): its folder, entries by computation, bytes on disk, the limit.
    ``{"location": None}`` when it is off; raises ``ValueError`` (naming the folder) where it cannot be opened."""
    location = cache_location()
    if location is None:
        return {"location": None, "off_by": f"{CACHE_DIR_ENV}={os.environ.get(CACHE_DIR_ENV)!r}"}
    limit = _max_bytes()
    if not location.exists():
        return {"location": str(location), "entries": {}, "bytes": 0, "limit_bytes": limit}
    cache = _opened(location, limit)
    entries: dict[str, int] = {}
    for key in cache.iterkeys():
        kind = str(key).rsplit("-", 1)[0]
        entries[kind] = entries.get(kind, 0) + 1
    return {"location": str(location), "entries": dict(sorted(entries.items())), "bytes": int(cache.volume()),
            "limit_bytes": limit}


def clear() -> dict:
    """Empty the cache (``rt2 cache clear``); what it held before (:func:`summary`)."""
    before = summary()
    if before["location"] is not None and Path(before["location"]).exists():
        _opened(Path(before["location"]), _max_bytes()).clear()
    return before


def _opened(location: Path, limit: int):
    """The ``diskcache.Cache`` of the existing folder ``location``; ``ValueError`` naming it where it cannot be opened."""
    if not location.is_dir():
        raise ValueError(f"the disk cache {str(location)!r} is not a folder (set {CACHE_DIR_ENV} to a folder, or to off)")
    import diskcache

    try:
        return diskcache.Cache(str(location), size_limit=limit, eviction_policy="least-recently-stored",
                               disk=_no_pickle_disk())
    except Exception as exc:  # noqa: BLE001 - one line naming the folder, not sqlite's traceback
        raise ValueError(f"the disk cache {str(location)!r} cannot be opened ({type(exc).__name__}: {exc}); "
                         f"delete the folder to start it afresh") from None


@functools.lru_cache(maxsize=1)
def _no_pickle_disk():
    """diskcache's ``Disk`` refusing every pickled key or value: its index can say "pickle" for a row planted in a
    shared folder, and diskcache would unpickle it; ours stores only str keys and bytes."""
    import diskcache
    from diskcache.core import MODE_PICKLE

    class NoPickleDisk(diskcache.Disk):
        def get(self, key, raw):
            if not raw:
                raise ValueError("a pickled key: rt2 never unpickles what it reads")
            return super().get(key, raw)

        def fetch(self, mode, filename, value, read):
            if mode == MODE_PICKLE:
                raise ValueError("a pickled value: rt2 never unpickles what it reads")
            return super().fetch(mode, filename, value, read)

    return NoPickleDisk


def _to_bytes(result, name: str) -> bytes:
    """``result`` (a dict of arrays) as the bytes of an uncompressed ``.npz`` archive."""
    import numpy as np

    if not isinstance(result, dict) or not all(isinstance(k, str) and isinstance(v, np.ndarray) and v.dtype != object
                                               for k, v in result.items()):
        raise TypeError(f"disk cache {name!r}: a result is a dict of numeric arrays, got {type(result).__name__}")
    buf = io.BytesIO()
    np.savez(buf, **result)
    return buf.getvalue()


def _from_bytes(data: bytes) -> dict:
    """The dict of arrays :func:`_to_bytes` stored (no pickle: objects are refused)."""
    import numpy as np

    with np.load(io.BytesIO(bytes(data)), allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


def _forget(cache, key: str) -> None:
    try:
        cache.delete(key)
    except Exception:  # noqa: BLE001 - best effort; the next store replaces it anyway
        pass
