"""Every ``rt2`` help page prints: the top level, each group's list of commands and each command's options.

argparse formats a command's line in its group's list with ``%``: a summary that says "within 20 %" made
``rt2 calib --help`` end in a traceback. Each page runs in this process (as ``rt2 X --help`` would).
"""

from __future__ import annotations

import pytest

from harness.cli import COMMANDS, main

GROUPS = sorted({words[0] for words in COMMANDS if len(words) > 1})
PAGES = [[]] + [[g] for g in GROUPS] + [list(words) for words in COMMANDS]


@pytest.mark.parametrize("words", PAGES, ids=[" ".join(w) or "rt2" for w in PAGES])
def test_help_page_prints_and_exits_0(capsys, words):
    with pytest.raises(SystemExit) as done:
        main([*words, "--help"])
    assert done.value.code == 0
    out, err = capsys.readouterr()
    assert out.startswith("usage: rt2") and "Traceback" not in out + err
    if len(words) == 1 and words[0] in GROUPS:  # a group's page lists each of its commands with its summary
        assert all(w[1] in out for w in COMMANDS if len(w) > 1 and w[0] == words[0])
