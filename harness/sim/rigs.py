"""Find a rig by name or path: what every ``--rig`` option of the ``rt2`` commands accepts.

``resolve_rig("lab4_vga")`` loads ``data/rigs/lab4_vga.yaml``; a path (absolute, relative, with or
without ``.yaml``) loads that file. Unknown names raise a ``ValueError`` listing the rigs available.
"""

from __future__ import annotations

from pathlib import Path

from tracker import Rig

__all__ = ["RIGS_DIR", "available_rigs", "resolve_rig", "rig_path"]

#: the project's rig files
RIGS_DIR = Path(__file__).resolve().parents[2] / "data" / "rigs"


def available_rigs() -> list[str]:
    """Names of the rigs in ``data/rigs`` (file stems), sorted."""
    return sorted(p.stem for p in RIGS_DIR.glob("*.yaml"))


def rig_path(name_or_path) -> Path:
    """The rig file meant by ``name_or_path``: an existing file, else ``data/rigs/<name>.yaml``."""
    text = str(name_or_path)
    if not text.strip():
        raise ValueError(f"--rig must name a rig {available_rigs()} or a rig file, got {text!r}")
    path = Path(text).expanduser()
    if path.is_file():
        return path
    if path.is_dir():
        raise ValueError(f"rig {text!r} is a folder; give a rig file (.yaml) or one of {available_rigs()}")
    if path.parent == Path(".") and path.suffix in ("", ".yaml", ".yml"):
        candidate = RIGS_DIR / (path.stem + ".yaml")
        if candidate.is_file():
            return candidate
    raise ValueError(f"unknown rig {text!r}: no such file, and not a rig in {RIGS_DIR}; available: {available_rigs()}")


def resolve_rig(name_or_path) -> Rig:
    """Load the rig named ``name_or_path`` (see the module docstring)."""
    if isinstance(name_or_path, Rig):
        return name_or_path
    return Rig.load(rig_path(name_or_path))
