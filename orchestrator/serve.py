"""Serving a simulation to other processes and hosts (``orchestrator launch --serve``).

The serving orchestrator owns the router and the node processes, and answers two queries:

- ``…/session``: the scenario (as a dict), the layout, the current episode — what a remote driver
  or a monitor needs to make sense of the bus;
- ``…/control``: ``{"claim": name}`` / ``{"release": name, "episode": n}`` — one driver at a time
  (e.g. ``ZenohEdgeEnv(connect=...)``) takes the clock; the server drives it otherwise.

A driver announces itself with the liveliness token ``…/alive/driver/<id>``; if it vanishes (the driver
crashed), the server takes the clock back. Episode numbers only grow, whoever drives, so node
processes can always tell late mail of an old episode from the current one.
"""

from __future__ import annotations

import contextlib
import secrets
import threading
from collections.abc import Iterator
from typing import Any

from node_runtime.keys import DEFAULT_PREFIX, Keys
from node_runtime.zenoh_transport import ZenohTransport
from orchestrator.clock import ClockError
from orchestrator.session import Simulation

DRIVER_PREFIX = "driver/"


class Busy(ClockError):
    """The clock is held by someone else."""


class Server:
    def __init__(self, sim: Simulation) -> None:
        if not isinstance(sim.transport, ZenohTransport):
            raise ValueError("only a simulation over Zenoh can be served")
        self.sim = sim
        self.driver: str | None = None
        self.running = False  # the server is running an episode itself
        self._lock = threading.Lock()
        sim.transport.serve(sim.keys.session(), self._session)
        sim.transport.serve(sim.keys.control(), self._control)
        sim.transport.watch_tokens(sim.keys.alive(f"{DRIVER_PREFIX}*"), self._on_driver_token)

    def _session(self, _: Any) -> dict[str, Any]:
        sim = self.sim
        with self._lock:
            return {"type": "session", "scenario": sim.scenario.to_dict(), "layout": sim.layout,
                    "episode": sim.clock.latest, "driver": self.driver, "procs": list(sim.routing.procs)}

    def _control(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            if "claim" in msg:
                if self.driver is not None or self.running:
                    who = self.driver or "the server's own episode"
                    return {"type": "control", "granted": False, "reason": f"the clock is held by {who}"}
                self.driver = msg["claim"]
                return {"type": "control", "granted": True, "episode": self.sim.clock.latest}
            if "release" in msg and msg["release"] == self.driver:
                self.driver = None
                self.sim.clock.catch_up(int(msg.get("episode", -1)))
                return {"type": "control", "released": True}
        return {"type": "control", "released": False}

    def _on_driver_token(self, key: str, alive: bool) -> None:
        name = DRIVER_PREFIX + key.rsplit("/", 1)[-1]
        with self._lock:
            if not alive and name == self.driver:  # the driver died without releasing
                self.driver = None

    @contextlib.contextmanager
    def own_clock(self) -> Iterator[None]:
        """Run the server's own episode; refused while a remote driver holds the clock."""
        with self._lock:
            if self.driver is not None:
                raise Busy(f"the clock is held by {self.driver}")
            self.running = True
            self.sim.clock.catch_up(self.sim.clock.latest)
        try:
            yield
        finally:
            with self._lock:
                self.running = False

    def wait(self, stop: threading.Event | None = None) -> None:
        """Serve until ``stop`` is set (or Ctrl-C), noticing dead processes meanwhile."""
        stop = stop or threading.Event()
        self.sim.transport.dispatch(until=stop.is_set, idle=self.sim.supervisor.check)


def describe(endpoint: str, sim_id: str, prefix: str = DEFAULT_PREFIX, timeout: float = 10.0) -> dict[str, Any]:
    """The session description of a served simulation, without taking its clock."""
    transport = ZenohTransport.client(endpoint)
    try:
        return transport.request(Keys(sim_id, prefix).session(), {"type": "session?"}, timeout=timeout)
    except Exception as exc:
        raise ClockError(f"no simulation {sim_id!r} answers at {endpoint}: {exc}") from None
    finally:
        transport.close()


def claim(transport: ZenohTransport, keys: Keys, timeout: float) -> tuple[dict[str, Any], str]:
    """Take the clock of a served simulation; returns its session description and our driver name."""
    try:
        info = transport.request(keys.session(), {"type": "session?"}, timeout=timeout)
    except Exception as exc:
        raise ClockError(f"no simulation {keys.sim_id!r} answers at this endpoint: {exc}") from None
    name = f"{DRIVER_PREFIX}{secrets.token_hex(3)}"
    answer = transport.request(keys.control(), {"type": "control", "claim": name}, timeout=timeout)
    if not answer.get("granted"):
        raise Busy(f"simulation {keys.sim_id}: {answer.get('reason', 'refused')}")
    info["episode"] = answer["episode"]
    return info, name


def release(transport: ZenohTransport, keys: Keys, name: str, episode: int) -> None:
    transport.request(keys.control(), {"type": "control", "release": name, "episode": episode}, timeout=5.0)
