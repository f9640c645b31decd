"""Arrival schedules answer rate, mean and peak as hand-computed (docs/scenario.md, "Workload")."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import TypeAdapter, ValidationError

from node_runtime.model.arrival import Arrival, Constant, Linear, Uniform, Zigzag

ARRIVAL = TypeAdapter(Arrival)


def test_the_kind_names_the_class_and_constant_is_the_default():
    assert ARRIVAL.validate_python({}) == Constant()
    assert isinstance(ARRIVAL.validate_python({"kind": "linear", "start": 0.1, "end": 0.3}), Linear)
    assert isinstance(ARRIVAL.validate_python({"kind": "uniform", "low": 0.1, "high": 0.3}), Uniform)


def test_constant():
    a = Constant(rate=0.2)
    assert (a.rate_at(0, 100), a.rate_at(99, 100), a.mean, a.peak) == (0.2, 0.2, 0.2, 0.2)


def test_linear_goes_from_start_to_end_over_the_episode():
    a = Linear(start=0.1, end=0.5)
    assert a.rate_at(0, 200) == pytest.approx(0.1)
    assert a.rate_at(50, 200) == pytest.approx(0.2)  # a quarter of the way: 0.1 + 0.4 / 4
    assert a.rate_at(400, 200) == pytest.approx(0.5)  # held at its end past the horizon
    assert (a.mean, a.peak) == (pytest.approx(0.3), 0.5)
    assert Linear(start=0.5, end=0.1).peak == 0.5


def test_zigzag_is_a_triangle_wave():
    a = Zigzag(low=0.1, high=0.3, period=20)
    # low at the start of each period, high half-way, back to low
    assert [a.rate_at(t, 1000) for t in (0, 5, 10, 15, 20, 30)] == pytest.approx([0.1, 0.2, 0.3, 0.2, 0.1, 0.3])
    assert (a.mean, a.peak) == (pytest.approx(0.2), 0.3)


def test_uniform_draws_a_rate_per_client():
    a = Uniform(low=0.1, high=0.3)
    draws = [a.client_rate(np.random.default_rng(s)) for s in range(200)]
    assert all(0.1 <= d < 0.3 for d in draws) and np.mean(draws) == pytest.approx(0.2, abs=0.02)
    assert Constant().client_rate(np.random.default_rng(0)) is None
    with pytest.raises(ValueError):
        a.rate_at(0, 100)


@pytest.mark.parametrize("data", [{"kind": "zigzag", "low": 0.3, "high": 0.1, "period": 5},
                                  {"kind": "constant", "rate": -1}, {"kind": "linear", "start": 1},
                                  {"kind": "linear", "start": 1, "end": 2, "rate": 3}])
def test_bad_schedules_are_refused(data):
    with pytest.raises(ValidationError):
        ARRIVAL.validate_python(data)
