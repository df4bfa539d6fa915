"""Shared CLI value parsers: X,Y,Z."""

from __future__ import annotations

import pytest

from planner.cli.args import parse_xyz
from planner.errors import InputError


def test_parse_xyz_numbers() -> None:
    assert parse_xyz("0.5,-0.25,1e-3", "--target") == [0.5, -0.25, 0.001]
    assert parse_xyz(" 1, 2 ,3", "--target") == [1.0, 2.0, 3.0]


@pytest.mark.parametrize(
    ("text", "words"),
    [("1,2", "expected X,Y,Z (3 numbers), got 2"), ("1,2,3,4", "got 4"),
     ("1,a,3", "expected X,Y,Z numbers"), ("", "expected X,Y,Z numbers")],
)  # fmt: skip
def test_parse_xyz_errors_name_the_option(text: str, words: str) -> None:
    with pytest.raises(InputError) as info:
        parse_xyz(text, "--mirror-centre")
    assert str(info.value).startswith(f"--mirror-centre {text!r}") and words in str(info.value)
