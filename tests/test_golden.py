"""The golden master's quick cases give the digests in tests/golden.json (tests/golden.py says how to
accept an intended change)."""

from __future__ import annotations

import math

import pytest

from tests import golden


@pytest.mark.parametrize("case", [c for c in golden.CASES if c.quick], ids=lambda c: c.name)
def test_golden_case(case):
    expected = golden.load()
    assert case.name in expected, f"{case.name} has no digest: run python -m tests.golden --update -k {case.name}"
    want = {k: v for k, v in expected[case.name].items() if k != "case"}
    assert golden.differences(want, golden.run_case(case)) == []


def test_every_case_has_a_digest_and_no_digest_is_stale():
    assert set(golden.load()) == {c.name for c in golden.CASES}


def test_the_digest_sees_one_changed_bit():
    assert golden._digest({"x": [0.1]}) != golden._digest({"x": [math.nextafter(0.1, 1.0)]})
    assert golden._digest({"a": 1.0}) != golden._digest({"a": 1})
