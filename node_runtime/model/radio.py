"""Communication model: Shannon–Hartley rates and the FIFO transmitter of a directed link (fixed, or
following the positions of moving nodes)."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from node_runtime.model.spec import Scenario

HIGH_SNR_DB = 3000.0  # beyond it 1 + 10^(snr/10) is 10^(snr/10) in double precision, and soon overflows


def dbm_to_watts(dbm: float) -> float:
    return 10.0 ** ((dbm - 30.0) / 10.0)


def shannon_rate(bandwidth_hz: float, tx_power_dbm: float, gain_db: float, noise_dbm: float) -> float:
    """r = B * log2(1 + 10^((P + G - w0) / 10)) in bit/s (the paper's Eq. 4)."""
    snr_db = tx_power_dbm + gain_db - noise_dbm
    if snr_db > HIGH_SNR_DB:  # so log2(1 + snr) is snr_db / 10 * log2(10)
        return bandwidth_hz * snr_db / 10.0 * math.log2(10.0)
    return bandwidth_hz * math.log2(1.0 + 10.0 ** (snr_db / 10.0))


SPEED_OF_LIGHT = 299_792_458.0  # m/s


def free_space_loss_db(distance_m: float, frequency_hz: float) -> float:
    """Free-space path loss 20 log10(4 pi d f / c): 40.05 dB at 1 m and 2.4 GHz."""
    return 20.0 * math.log10(4.0 * math.pi * distance_m * frequency_hz / SPEED_OF_LIGHT)


def log_distance_gain_db(distance_m: float, ref_loss_db: float, ref_distance_m: float,
                         exponent: float) -> float:
    """Channel gain (negative path loss) of the log-distance model.

    PL(d) = PL(d0) + 10 n log10(d / d0) for d >= d0; closer than d0 the loss is PL(d0).
    """
    d = max(distance_m, ref_distance_m)
    return -(ref_loss_db + 10.0 * exponent * math.log10(d / ref_distance_m))


class LinkTransmitter:
    """One directed link: transmits one message at a time, first in, first out.

    Time is kept in ticks (floats) so that ``dt`` never introduces rounding drift: a message of b
    bits sent in tick t starts when the link frees up, occupies it for b / r / dt ticks, and is
    delivered at the first tick boundary after it finishes — but never before t + 1.

    It also keeps the airtime of the charged messages still queued (a worker's offloaded tasks, each
    under its task's id), to tell what waiting each imposes on every later message: the delay a decision
    imposes on others.
    """

    __slots__ = ("busy_until", "charged", "dt", "rate_bps")

    def __init__(self, rate_bps: float, dt: float) -> None:
        self.rate_bps = rate_bps
        self.dt = dt
        self.reset()

    def reset(self) -> None:
        self.busy_until = 0.0
        self.charged: deque[tuple[float, float, int]] = deque()  # (start, finish) in ticks, task id; in sending order

    def send(self, tick: int, bits: float, charged: int | None = None) -> tuple[int, float, list[tuple[int, float]]]:
        """Queue a message (``charged``: the id of the task whose offload it is); return its arrival tick,
        its seconds on air, and the seconds it waits for each charged message ahead of it (task id, seconds)."""
        seconds = bits / self.rate_bps
        start = max(float(tick), self.busy_until)
        finish = start + seconds / self.dt
        return max(tick + 1, math.ceil(finish)), seconds, self.occupy(tick, start, finish, charged)

    def occupy(self, tick: int, start: float, finish: float, charged: int | None) -> list[tuple[int, float]]:
        """The link is busy from ``start`` to ``finish`` (ticks) with a message sent in ``tick``: the seconds it
        waits for each charged message ahead of it."""
        self.busy_until = finish
        queued = self.charged
        while queued and queued[0][1] <= tick:
            queued.popleft()
        now = float(tick)
        ahead = [(task, (f - max(now, s)) * self.dt) for s, f, task in queued]  # their airtime left ahead of it
        if charged is not None:
            queued.append((start, finish, charged))
        return ahead


class MovingLink(LinkTransmitter):
    """A link with a moving end: in each tick it carries bits at the rate of that tick's distance, and it does
    not exist in a tick its ends are out of range. A transfer that meets such a tick breaks there: it is lost,
    or (``retry``) sent again whole from the first tick the link is back, if that tick is not past the deadline
    of the message's task nor past the episode's end."""

    __slots__ = ("horizon", "rate_at", "retry")

    def __init__(self, rate_at: Callable[[int], float], dt: float, retry: bool, horizon: int) -> None:
        self.rate_at = rate_at
        self.retry = retry
        self.horizon = horizon  # the episode's last tick: a message waits for its link no later
        super().__init__(0.0, dt)

    def carry(self, tick: int, bits: float, latest_start: float,
              charged: int | None = None) -> tuple[int, float, list[tuple[int, float]]] | str:
        """``LinkTransmitter.send`` over the ticks' rates, or "link_broken"."""
        start = at = max(float(tick), self.busy_until)
        k = math.floor(at)
        left, airtime = bits, 0.0
        while True:
            rate = self.rate_at(k)
            if rate <= 0.0:  # out of range in tick k: it breaks here, or cannot start
                back = self.back(k, latest_start) if self.retry else None
                if back is None:  # the link was busy with it until it broke (charged only if it was on air)
                    self.occupy(tick, start, at, charged if at > start else None)
                    return "link_broken"
                at, k, left = float(back), back, bits
                continue
            fits = rate * self.dt * (k + 1 - at)  # bits it carries in the rest of tick k
            if left <= fits:
                airtime += left / rate
                finish = at + left / (rate * self.dt)
                return max(tick + 1, math.ceil(finish)), airtime, self.occupy(tick, start, finish, charged)
            left -= fits
            airtime += fits / rate
            at = float(k + 1)
            k += 1

    def back(self, k: int, latest_start: float) -> int | None:
        """The first tick after ``k`` in which the link exists again, if a message may start then."""
        last = min(latest_start, float(self.horizon))
        k += 1
        while k <= last:
            if self.rate_at(k) > 0.0:
                return k
            k += 1
        return None


class Radio:
    """A node's outgoing links: one FIFO transmitter per neighbour, each with its loss probability."""

    def __init__(self, links: dict[str, tuple[float, float]], dt: float) -> None:
        """``links`` maps a neighbour to (rate in bit/s, loss probability)."""
        self.links = {j: LinkTransmitter(rate, dt) for j, (rate, _) in links.items()}
        self.loss = {j: loss for j, (_, loss) in links.items()}
        self.rng: np.random.Generator | None = None

    @classmethod
    def for_node(cls, scenario: Scenario, node: str, dsts: tuple[str, ...],
                 rate: Callable[[str, str, int], float] | None = None) -> Radio:
        """``rate(src, dst, tick)``: the rate of a link with a moving end in a tick (``Positions.rate``), in a
        scenario where nodes move (those links are ``MovingLink``s)."""
        radio = cls({j: (scenario.link[(node, j)].rate_bps, scenario.link[(node, j)].loss) for j in dsts},
                    scenario.dt)
        for j in dsts:
            if scenario.moving_link(node, j):
                radio.links[j] = MovingLink(partial(rate, node, j), scenario.dt,
                                            scenario.radio.on_break == "retry", scenario.episode_ticks - 1)
        return radio

    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng
        for link in self.links.values():
            link.reset()

    def busy_until(self) -> list[float]:
        """When each link (in neighbour order) finishes what is queued on it, in ticks."""
        return [link.busy_until for link in self.links.values()]

    def __contains__(self, node: str) -> bool:
        return node in self.links

    def send(self, tick: int, dst: str, bits: float, latest_start: float = math.inf,
             charged: int | None = None) -> tuple[int, float, list[tuple[int, float]]] | str:
        """(arrival tick, seconds on air, seconds it waits for each charged message; ``LinkTransmitter.send``),
        or why the message never arrives: "expired", "link_broken" (``MovingLink``) or "link_loss".

        A message whose transmission could only start after ``latest_start`` (in ticks: its task's
        deadline) is never sent and takes no airtime: a sender does not transmit an expired task, so a
        backlog cannot grow without bound behind tasks that are already lost. A lost message did
        occupy the link, as a real transmission would.
        """
        link = self.links[dst]
        if max(float(tick), link.busy_until) > latest_start:
            return "expired"
        sent = link.carry(tick, bits, latest_start, charged) if isinstance(link, MovingLink) else \
            link.send(tick, bits, charged)
        if isinstance(sent, str):
            return sent
        loss = self.loss[dst]
        if loss > 0.0 and self.rng.random() < loss:
            return "link_loss"
        return sent
