"""generate's numeric options stand in for params keys and are held to the same ranges as
the params file's (mimicgen_pipe.params): one line naming the option, the value and the
range, exit 2, before any work (a real ``mimicgen-pipe generate``)."""

from __future__ import annotations

import pytest

from tests.test_cli_errors import run_bad


@pytest.mark.parametrize(
    ("option", "value", "expected"),
    [
        ("--attempts", "1000000000000", "[1, 10000000] (the range of generate.max_attempts)"),
        ("--attempts", "0", "[1, 10000000] (the range of generate.max_attempts)"),
        ("--action-noise", "inf", "[0.0, 1.0] (the range of generate.action_noise)"),
        ("--action-noise", "nan", "[0.0, 1.0] (the range of generate.action_noise)"),
    ],
)
def test_an_option_out_of_its_keys_range_is_one_error(tmp_path, option, value, expected):
    msg = run_bad(tmp_path, "generate", "--variant", "D0", option, value)
    shown = repr(float(value)) if option == "--action-noise" else value
    assert msg == (
        f"mimicgen-pipe generate: error: {option} {shown}: expected a value in {expected}, "
        f"got {shown}"
    )
