"""The tools' number options (client/arguments.py) as motorctl parses them: ``nan``, ``inf``,
a negative or no number at all is a usage error naming the option and the range, never a
value taken (``replay --answer-timeout inf`` was an OverflowError from poll() mid-replay,
``nan`` a tolerance nothing compared with, a negative one a replay stopped at once)."""

from __future__ import annotations

import pytest

from motorctl.client.arguments import number_in, whole_in
from motorctl.client.cli import build_parser

PORTS = ["--host", "a", "--device", "b", "--out", "c"]


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["replay", "t.pcapng", "--answer-timeout", "inf"], "'inf' is not a number more than 0"),
        (["replay", "t.pcapng", "--answer-timeout", "0"], "'0' is not a number more than 0"),
        (["replay", "t.pcapng", "--answer-timeout", "nan"], "at most 86400 s"),
        (["replay", "t.pcapng", "--time-tolerance-ms", "nan"], "'nan' is not a number at least 0"),
        (["replay", "t.pcapng", "--time-tolerance-ms", "-5"], "'-5' is not a number at least 0"),
        (["replay", "t.pcapng", "--slide-tolerance", "inf"], "at most 1000 %"),
        (["replay", "t.pcapng", "--position-tolerance", "-5"], "-5 is not in 0..16777216 steps"),
        (["replay", "t.pcapng", "--position-tolerance", "2.5"], "'2.5' is not a whole number"),
        (["trace", "t.pcapng", "--frame-gap-ms", "-1"], "'-1' is not a number at least 0"),
        (["trace", "t.pcapng", "--frame-gap-ms", "inf"], "at most 10000 ms"),
        (["tap", *PORTS, "--frame-gap-ms", "nan"], "'nan' is not a number at least 0"),
        (["tap", *PORTS, "--frame-gap-ms", "soon"], "'soon' is not a number at least 0"),
    ],
)
def test_a_number_option_out_of_its_range_is_a_usage_error(
    args: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    option = args[-2]
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args([" " + a if a.startswith("-5") else a for a in args])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"error: argument {option}: " in err and says in err


def test_numbers_in_range_are_taken_as_they_are() -> None:
    assert number_in(0, 10, "ms")("0") == 0.0 and number_in(0, 10, "ms")("10") == 10.0
    assert number_in(0, 10, "s", lo_open=True)("0.5") == 0.5
    assert whole_in(0, 5, "steps")("5") == 5
    parsed = build_parser().parse_args(["replay", "t.pcapng", "--answer-timeout", "2.5"])
    assert parsed.answer_timeout == 2.5 and parsed.position_tolerance == 2
