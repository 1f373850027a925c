"""Progress bars in logs: plain whole lines, throttled, when the stream is not a terminal."""

from __future__ import annotations

import io

from harness.common.progress import PLAIN_INTERVAL_S, progress_bar


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_log_gets_whole_lines_at_most_every_few_seconds(monkeypatch):
    monkeypatch.delenv("TQDM_MININTERVAL", raising=False)
    log = io.StringIO()
    with progress_bar(total=1000, desc="work", file=log) as bar:
        for _ in range(1000):
            bar.update(1)
    text = log.getvalue()
    assert "\r" not in text and text.endswith("\n")
    lines = text.splitlines()
    assert 1 <= len(lines) <= 3, lines  # the first draw, the last one; 1000 updates in well under 5 s
    assert lines[-1].startswith("work: 100%") and "1000/1000" in lines[-1]
    assert PLAIN_INTERVAL_S >= 1.0


def test_tqdm_mininterval_zero_draws_every_update(monkeypatch):
    monkeypatch.setenv("TQDM_MININTERVAL", "0")
    log = io.StringIO()
    bar = progress_bar(total=5, desc="work", file=log, leave=False)
    for _ in range(5):
        bar.update(1)
    bar.close()
    assert [ln.split("|")[-1].split()[0] for ln in log.getvalue().splitlines()] == [f"{i}/5" for i in range(6)]


def test_a_terminal_keeps_tqdms_own_redraws(monkeypatch):
    monkeypatch.delenv("TQDM_MININTERVAL", raising=False)
    tty = Terminal()
    with progress_bar(total=3, desc="work", file=tty, mininterval=0) as bar:
        bar.update(3)
    assert "\r" in tty.getvalue()


def test_a_bad_interval_in_the_environment_falls_back(monkeypatch):
    for bad in ("fast", "-1"):
        monkeypatch.setenv("TQDM_MININTERVAL", bad)
        log = io.StringIO()
        bar = progress_bar(total=2, desc="work", file=log)
        assert bar.mininterval == PLAIN_INTERVAL_S
        bar.close()
