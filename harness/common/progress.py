"""Progress bars that keep logs readable: tqdm's bar on a terminal, a plain line every few seconds elsewhere.

    bar = progress_bar(total=n, desc="sim table1", unit="chunk", disable=not show)   # same arguments as tqdm

When the bar's stream (stderr by default) is not a terminal (a CI log, a pipe, a file), tqdm's redraws
(``\\r`` + the whole bar, up to ten a second) would pile up on one line of the log. There the bar is drawn at
most once every ``PLAIN_INTERVAL_S`` seconds (tqdm's ``mininterval``; the environment variable
``TQDM_MININTERVAL`` sets another interval, ``0`` draws every update), in ASCII, one whole line per
draw. A terminal keeps tqdm's own behaviour. An explicit ``mininterval=`` or ``ascii=`` wins.
"""

from __future__ import annotations

import os
import sys

from tqdm import tqdm

__all__ = ["PLAIN_INTERVAL_S", "progress_bar"]

PLAIN_INTERVAL_S = 5.0  #: seconds between two progress lines when the stream is not a terminal


class _Lines:
    """The stream tqdm writes to, turning its carriage-return redraws into whole lines (none for a blank)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> None:
        line = text.replace("\r", "").strip()
        if line:
            self._stream.write(line + "\n")

    def flush(self) -> None:
        self._stream.flush()


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):  # no isatty, or a closed stream
        return False


def _plain_interval_s() -> float:
    text = os.environ.get("TQDM_MININTERVAL", "")
    try:
        value = float(text)
    except ValueError:
        return PLAIN_INTERVAL_S
    return value if value >= 0 else PLAIN_INTERVAL_S


def progress_bar(iterable=None, *, file=None, **kwargs) -> tqdm:
    """A ``tqdm`` bar on ``file`` (default stderr), throttled to plain lines when ``file`` is not a terminal."""
    stream = sys.stderr if file is None else file
    if not _is_terminal(stream):
        kwargs.setdefault("mininterval", _plain_interval_s())
        kwargs.setdefault("ascii", True)
        stream = _Lines(stream)
    return tqdm(iterable, file=stream, **kwargs)
