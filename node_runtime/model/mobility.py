"""Moving nodes, as a scenario states them: a node's mobility model (random waypoint, Gauss–Markov, or a
trace of timed positions, which a CSV file or SUMO's FCD output is read into when the scenario is resolved)
and the radio range of their links. ``positions`` computes where they are; the rules are docs/model.md's
"Moving nodes"."""

from __future__ import annotations

from itertools import pairwise
from typing import Annotated, Any, Literal

from pydantic import Discriminator, Field, Tag, model_validator

from node_runtime.model.values import Decibels, NonNeg, Pos, Prob, Strict

Point = tuple[float, float]
Box = tuple[float, float, float, float]  # x0, y0, x1, y1


class Area(Strict):
    """A rectangle, ``[[x0, y0], [x1, y1]]`` in the file, with x0 < x1 and y0 < y1 (metres)."""

    low: Point
    high: Point

    @model_validator(mode="before")
    @classmethod
    def _corners(cls, v: Any) -> Any:
        if isinstance(v, list | tuple) and len(v) == 2:
            return {"low": v[0], "high": v[1]}
        return v

    @model_validator(mode="after")
    def _extent(self) -> Area:
        if not (self.low[0] < self.high[0] and self.low[1] < self.high[1]):
            raise ValueError("expected [[x0, y0], [x1, y1]] with x0 < x1 and y0 < y1")
        return self

    def contains(self, p: Point) -> bool:
        return self.low[0] <= p[0] <= self.high[0] and self.low[1] <= p[1] <= self.high[1]

    @property
    def box(self) -> Box:
        return (*self.low, *self.high)


class RandomWaypoint(Strict):
    """From its position, a node walks in a straight line to a waypoint drawn uniformly in ``area``, at a
    speed drawn from U[low, high] m/s, pauses ``pause`` seconds there, and draws the next leg."""

    model: Literal["random_waypoint"] = "random_waypoint"
    area: Area
    speed: tuple[Pos, Pos]  # [low, high] m/s
    pause: NonNeg = 0.0  # seconds at each waypoint

    @model_validator(mode="after")
    def _speeds(self) -> RandomWaypoint:
        if self.speed[1] < self.speed[0]:
            raise ValueError("speed: expected [low, high] with low <= high")
        return self


class GaussMarkov(Strict):
    """Speed and direction are first-order Gauss–Markov processes, updated every tick (Liang and Haas):
    s' = α·s + (1 − α)·s̄ + √(1 − α²)·σ_s·w, the same for the direction; the node moves s·dt along its
    direction and is reflected by the sides of ``area``. Directions in degrees, counter-clockwise from +x."""

    model: Literal["gauss_markov"] = "gauss_markov"
    area: Area
    alpha: Prob  # memory: 1 keeps speed and direction, 0 draws them afresh every tick
    speed: NonNeg  # mean speed s̄, m/s (also the first speed)
    direction: Annotated[float, Field(ge=-360, le=360)] = 0.0  # mean direction d̄ (also the first one)
    speed_sigma: NonNeg = 0.0  # σ_s, m/s
    direction_sigma: NonNeg = 0.0  # σ_d, degrees


class Trace(Strict):
    """Timed positions (seconds, x, y), in time order: linear interpolation between them, the first before
    the first and the last after the last. Resolved from a trace CSV (``t,node,x,y``) or SUMO FCD output."""

    model: Literal["trace"] = "trace"
    samples: Annotated[tuple[tuple[float, float, float], ...], Field(min_length=1)]

    @model_validator(mode="after")
    def _ordered(self) -> Trace:
        times = [s[0] for s in self.samples]
        if any(b <= a for a, b in pairwise(times)):
            raise ValueError("expected samples in strictly increasing time")
        return self


MODEL_ERROR = "mobility_model"  # the error type of a ``model`` no class answers to
MODELS = ("random_waypoint", "gauss_markov", "trace")


def model_of(value: Any) -> str | None:
    model = value.get("model") if isinstance(value, dict) else getattr(value, "model", None)
    return f"<{model}>" if isinstance(model, str) else None


# A node's movement: the model names the class. Tags are written <model> so that error paths skip them.
Mobility = Annotated[
    Annotated[RandomWaypoint, Tag("<random_waypoint>")] | Annotated[GaussMarkov, Tag("<gauss_markov>")]
    | Annotated[Trace, Tag("<trace>")],
    Discriminator(model_of, custom_error_type=MODEL_ERROR,
                  custom_error_message=f"expected a model among {', '.join(map(repr, MODELS))}"),
]


class RadioRange(Strict):
    """The radio of links with a moving end (``Scenario.radio``): the file's network settings, resolved, and
    the range beyond which such a link does not exist."""

    range_m: Pos
    on_break: Literal["drop", "retry"] = "drop"  # a transfer whose link breaks: lost, or sent again whole
    bandwidth_hz: Pos
    noise_dbm: Decibels
    ref_loss_db: Decibels
    ref_distance_m: Pos
    exponent: Pos
