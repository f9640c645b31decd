"""Where the nodes are at any tick, and the rate of a link with a moving end in that tick.

Positions are a function of the scenario and the seed alone: every process that needs one computes it, the
same, and no position crosses the bus. A walk's draws come from a stream of its own per node
(``rng.MOBILITY``), so moving nodes leave every other draw where it was (docs/model.md, "Moving nodes").
"""

from __future__ import annotations

import math
from bisect import bisect_right
from typing import TYPE_CHECKING, Any

import numpy as np

from node_runtime.model.mobility import Area, Box, GaussMarkov, Point, RadioRange, RandomWaypoint, Trace
from node_runtime.model.radio import log_distance_gain_db, shannon_rate
from node_runtime.model.rng import MOBILITY, stream

if TYPE_CHECKING:
    from node_runtime.model.spec import Scenario

def link_rate(radio: RadioRange, tx_power_dbm: float, distance_m: float) -> float:
    """Shannon–Hartley over log-distance path loss at ``distance_m``; 0 beyond the range."""
    if distance_m > radio.range_m:
        return 0.0
    gain = log_distance_gain_db(distance_m, radio.ref_loss_db, radio.ref_distance_m, radio.exponent)
    return shannon_rate(radio.bandwidth_hz, tx_power_dbm, gain, radio.noise_dbm)


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
        self.points = [self.start]
        self.begin()

    def at(self, tick: int) -> Point:
        points = self.points
        if tick < len(points):
            return points[tick]
        while len(points) <= tick:
            points.append(self.step(*points[-1]))
        return points[tick]

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
        self.range_m = scenario.radio.range_m
        self.index = scenario.index
        self.power = {n.id: n.tx_power_dbm for n in scenario.nodes}
        self.tracks = {n.id: track(n.mobility, n.position, scenario.dt) for n in scenario.nodes}

    def reset(self, seed: int) -> None:
        for node, t in self.tracks.items():
            t.reset(stream(seed, self.index[node], MOBILITY))

    def at(self, node: str, tick: int) -> Point:
        return self.tracks[node].at(tick)

    def distance(self, a: str, b: str, tick: int) -> float:
        tracks = self.tracks
        return math.dist(tracks[a].at(tick), tracks[b].at(tick))

    def in_range(self, a: str, b: str, tick: int) -> bool:
        """Whether the link between ``a`` and ``b`` exists in ``tick``."""
        tracks = self.tracks
        return math.dist(tracks[a].at(tick), tracks[b].at(tick)) <= self.range_m

    def rate(self, src: str, dst: str, tick: int) -> float:
        """The rate of the radio link src -> dst during ``tick``: 0 while they are out of range."""
        return link_rate(self.radio, self.power[src], self.distance(src, dst, tick))
