"""A command's bad option values, named by the option the user typed.

The dataclasses a command fills from its options (``TrainOptions``, ``AutoOptions``, ``AccuracyConfig``, ...) name
their own fields in their errors ("TrainOptions.augment_copies must be an integer >= 0"): code that builds them reads
those; the user typed ``--augment``. :func:`named_by_options` re-raises such an error as one with each
``Owner.field`` replaced by the option that fills it (``rt2 live``'s :class:`harness.live.config.ConfigError` does the
same for its own fields with ``{field}`` placeholders).
"""

from __future__ import annotations

from contextlib import contextmanager

__all__ = ["named_by_options"]


@contextmanager
def named_by_options(owner: str, flags: dict[str, str], phrases: dict[str, str] | None = None):
    """Inside, a ValueError's message has each ``"{owner}.{field} "`` of ``flags`` ``{field: option}`` replaced by
    ``"{option} "`` (after the whole ``phrases`` ``{text: replacement}``, for sentences that name two fields), and is
    raised again as a ValueError, without the chain (one line for the user)."""
    try:
        yield
    except ValueError as exc:
        message = str(exc)
        for text, replacement in (phrases or {}).items():
            message = message.replace(text, replacement)
        for field, flag in flags.items():
            message = message.replace(f"{owner}.{field} ", f"{flag} ")
        raise ValueError(message) from None
