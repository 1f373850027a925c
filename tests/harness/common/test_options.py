"""``named_by_options``: a config's field errors re-raised with the option the user typed."""

from __future__ import annotations

import pytest

from harness.common.options import named_by_options

FLAGS = {"learned": "--learned", "learned_steps": "--learned-steps"}


@pytest.mark.parametrize("raised, shown", [
    ("Opts.learned_steps must be a positive integer, got 0", "--learned-steps must be a positive integer, got 0"),
    ("Opts.learned must be one of ('on', 'off'), got 'x'", "--learned must be one of ('on', 'off'), got 'x'"),  # not --learned-steps
    ("Other.learned must be one of", "Other.learned must be one of"),  # another owner's field: as it was
    ("no field named here", "no field named here"),
    ("Opts.filter 'keep' with learned 'off' trains nothing", "--filter keep with --learned off trains nothing"),  # a phrase first
])
def test_a_field_is_named_by_its_option(raised, shown):
    with pytest.raises(ValueError) as err:
        with named_by_options("Opts", FLAGS, {"Opts.filter 'keep' with learned 'off'": "--filter keep with --learned off"}):
            raise ValueError(raised)
    assert str(err.value) == shown and type(err.value) is ValueError and err.value.__cause__ is None


def test_other_errors_and_no_error_pass_through():
    with named_by_options("Opts", FLAGS):
        pass
    with pytest.raises(KeyError):
        with named_by_options("Opts", FLAGS):
            raise KeyError("learned")
