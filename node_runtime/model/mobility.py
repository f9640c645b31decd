"""Moving nodes: each node's position at every tick, and the rate of a radio link between moving nodes.

A node moves by random waypoint, Gauss–Markov, or a trace of timed positions (a CSV file or SUMO's
FCD output, read into samples when the scenario is resolved). Positions are a function of the scenario
and the seed alone: every process that needs one computes it, the same, and no position crosses the bus.
A walk's draws come from a stream of its own per node (``rng.MOBILITY``), so moving nodes leave every
other draw where it was. The rules are docs/model.md's "Moving nodes".
"""

from __future__ import annotations

import math
from bisect import bisect_right
from itertools import pairwise
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import Discriminator, Field, Tag, model_validator

from node_runtime.model.radio import log_distance_gain_db, shannon_rate
from node_runtime.model.rng import MOBILITY, stream
from node_runtime.model.values import Decibels, NonNeg, Pos, Prob, Strict

if TYPE_CHECKING:
    from node_runtime.model.spec import Scenario

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

    def rate(self, tx_power_dbm: float, distance_m: float) -> float:
        """Shannon–Hartley over log-distance path loss at ``distance_m``; 0 beyond the range."""
        if distance_m > self.range_m:
            return 0.0
        gain = log_distance_gain_db(distance_m, self.ref_loss_db, self.ref_distance_m, self.exponent)
        return shannon_rate(self.bandwidth_hz, tx_power_dbm, gain, self.noise_dbm)


# ----- tracks: one node's positions, tick by tick -----

class Still:
    """A node that does not move."""

    def __init__(self, position: Point) -> None:
        self.position = position

    def reset(self, rng: np.random.Generator) -> None:
        pass

    def at(self, tick: int) -> Point:
        return self.position


class Sampled:
    """A trace, interpolated at tick × dt."""

    def __init__(self, model: Trace, dt: float) -> None:
        self.times = [s[0] for s in model.samples]
        self.points = [(s[1], s[2]) for s in model.samples]
        self.dt = dt

    def reset(self, rng: np.random.Generator) -> None:
        pass

    def at(self, tick: int) -> Point:
        return interpolate(self.times, self.points, tick * self.dt)


def interpolate(times: list[float], points: list[Point], t: float) -> Point:
    """The position at ``t`` on straight lines between timed points; the end points outside them."""
    i = bisect_right(times, t)
    if i == 0:
        return points[0]
    if i == len(times):
        return points[-1]
    t0, t1 = times[i - 1], times[i]
    (x0, y0), (x1, y1) = points[i - 1], points[i]
    f = (t - t0) / (t1 - t0)
    return (x0 + f * (x1 - x0), y0 + f * (y1 - y0))


class Walk:
    """A random walk: positions computed one tick after the other, as far as asked, and kept for the episode."""

    def __init__(self, start: Point, dt: float) -> None:
        self.start = start
        self.dt = dt

    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.xs, self.ys = [self.start[0]], [self.start[1]]
        self.begin()

    def at(self, tick: int) -> Point:
        while len(self.xs) <= tick:
            x, y = self.step(self.xs[-1], self.ys[-1])
            self.xs.append(x)
            self.ys.append(y)
        return (self.xs[tick], self.ys[tick])

    def begin(self) -> None:
        """Draw what the walk needs before its first step."""

    def step(self, x: float, y: float) -> Point:
        """The position one tick after (x, y)."""
        raise NotImplementedError


class WaypointWalk(Walk):
    """Random waypoint, in continuous time: a tick may end a leg, a pause and start the next leg. Each leg
    draws x, y of its waypoint, then its speed, from the node's stream."""

    def __init__(self, model: RandomWaypoint, start: Point, dt: float) -> None:
        super().__init__(start, dt)
        self.model = model

    def begin(self) -> None:
        self.paused = 0.0  # seconds of pause left
        self.leg()

    def leg(self) -> None:
        (x0, y0), (x1, y1) = self.model.area.low, self.model.area.high
        self.target = (float(self.rng.uniform(x0, x1)), float(self.rng.uniform(y0, y1)))
        self.speed = float(self.rng.uniform(*self.model.speed))

    def step(self, x: float, y: float) -> Point:
        left = self.dt
        while left > 0.0:
            if self.paused > 0.0:
                spent = min(self.paused, left)
                self.paused -= spent
                left -= spent
                if self.paused <= 0.0:
                    self.leg()
                continue
            tx, ty = self.target
            to_go = math.hypot(tx - x, ty - y) / self.speed
            if to_go > left:
                f = left / to_go
                return (x + f * (tx - x), y + f * (ty - y))
            x, y = tx, ty
            left -= to_go
            self.paused = self.model.pause
            if self.paused <= 0.0:
                self.leg()
        return (x, y)


class GaussMarkovWalk(Walk):
    """Gauss–Markov: each tick moves by the current speed and direction, then draws the next ones (two
    standard normals, speed first). Movement uses max(s, 0); a side of the area reflects the node and its
    direction."""

    def __init__(self, model: GaussMarkov, start: Point, dt: float) -> None:
        super().__init__(start, dt)
        self.model = model

    def begin(self) -> None:
        self.speed = self.model.speed
        self.direction = math.radians(self.model.direction)

    def step(self, x: float, y: float) -> Point:
        m = self.model
        distance = max(self.speed, 0.0) * self.dt
        x, y, self.direction = reflect(x + distance * math.cos(self.direction),
                                       y + distance * math.sin(self.direction), self.direction, m.area)
        w_speed, w_direction = self.rng.standard_normal(2)
        keep, spread = m.alpha, math.sqrt(1.0 - m.alpha * m.alpha)
        self.speed = keep * self.speed + (1.0 - keep) * m.speed + spread * m.speed_sigma * float(w_speed)
        self.direction = (keep * self.direction + (1.0 - keep) * math.radians(m.direction)
                          + spread * math.radians(m.direction_sigma) * float(w_direction))
        return (x, y)


def reflect(x: float, y: float, direction: float, area: Area) -> tuple[float, float, float]:
    """(x, y) folded back into ``area`` by its sides, and the direction mirrored by each side it crossed."""
    (x0, y0), (x1, y1) = area.low, area.high
    while not x0 <= x <= x1:
        x = 2 * x0 - x if x < x0 else 2 * x1 - x
        direction = math.pi - direction
    while not y0 <= y <= y1:
        y = 2 * y0 - y if y < y0 else 2 * y1 - y
        direction = -direction
    return x, y, direction


def track(model: Any, start: Point, dt: float) -> Still | Sampled | Walk:
    if model is None:
        return Still(start)
    if isinstance(model, Trace):
        return Sampled(model, dt)
    if isinstance(model, RandomWaypoint):
        return WaypointWalk(model, start, dt)
    return GaussMarkovWalk(model, start, dt)


def bounds(model: Any, start: Point) -> Box:
    """Where a node can ever be: the box a link's range is measured against when the scenario is resolved."""
    if model is None:
        return (*start, *start)
    if isinstance(model, Trace):
        xs, ys = [s[1] for s in model.samples], [s[2] for s in model.samples]
        return (min(xs), min(ys), max(xs), max(ys))
    return model.area.box


def box_distance(a: Box, b: Box) -> float:
    """The least distance between a point of box ``a`` and one of box ``b``."""
    dx = max(a[0] - b[2], b[0] - a[2], 0.0)
    dy = max(a[1] - b[3], b[1] - a[3], 0.0)
    return math.hypot(dx, dy)


class Positions:
    """Every node's position at any tick of an episode, computed where it is asked for."""

    def __init__(self, scenario: Scenario) -> None:
        self.radio = scenario.radio
        self.index = scenario.index
        self.power = {n.id: n.tx_power_dbm for n in scenario.nodes}
        self.tracks = {n.id: track(n.mobility, n.position, scenario.dt) for n in scenario.nodes}

    def reset(self, seed: int) -> None:
        for node, t in self.tracks.items():
            t.reset(stream(seed, self.index[node], MOBILITY))

    def at(self, node: str, tick: int) -> Point:
        return self.tracks[node].at(tick)

    def distance(self, a: str, b: str, tick: int) -> float:
        return math.dist(self.at(a, tick), self.at(b, tick))

    def in_range(self, a: str, b: str, tick: int) -> bool:
        """Whether the link between ``a`` and ``b`` exists in ``tick``."""
        return self.distance(a, b, tick) <= self.radio.range_m

    def rate(self, src: str, dst: str, tick: int) -> float:
        """The rate of the radio link src -> dst during ``tick``: 0 while they are out of range."""
        return self.radio.rate(self.power[src], self.distance(src, dst, tick))
