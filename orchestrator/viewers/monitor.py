"""``orchestrator monitor``: watch a running simulation live, from this host or another one.

    orchestrator monitor                                           # the only simulation launched on this host
    orchestrator monitor --connect tcp/10.0.0.1:7447 --sim lab1 --json | jq .delta

Without ``--connect`` it follows a simulation that this user's ``orchestrator launch`` listed on this
host (``orchestrator.local_sims``); with it, one behind that router.

The monitor only subscribes (``…/metrics/tick``, ``…/events/offloaded/*``, the orchestrator's
liveliness token) and asks ``…/session``; it never publishes. Metrics and events travel on
best-effort publishers that drop rather than block, so attaching or detaching at any time changes
nothing in the run (docs/bus.md).

Three layers: ``BusMonitor`` is the bus side (discovery and subscriptions, over any ``Transport``); ``DashboardState``
folds the messages into a small state; ``render`` turns a state into a rich renderable, a pure
function that tests drive with recorded messages and no terminal.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rich import box
from rich.console import Console, Group, RenderableType
from rich.live import Live
from rich.table import Table
from rich.text import Text

from node_runtime.runtime.cli_options import add_security_options, add_sim_options, security_options
from node_runtime.runtime.codec import CodecError
from node_runtime.runtime.keys import DEFAULT_PREFIX, Keys
from node_runtime.runtime.process import ORCHESTRATOR
from node_runtime.runtime.security import Security, SecurityError
from node_runtime.runtime.transport import Handler, TokenHandler, Transport, TransportError
from node_runtime.runtime.zenoh_bus import ZenohTransport
from orchestrator import local_sims
from orchestrator.catalogue import METRIC, Agg, Form, Metric, Out, shown
from orchestrator.units import quantity

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
WINDOW_TICKS = 100  # ticks behind the task rates, utilisation and offload flows
RT_WINDOW = 1000  # samples (completions) behind the response-time percentiles
RATE_WINDOW_S = 3.0  # wall seconds behind the measured tick rate
IDLE_S = 2.0  # no tick for this long: say so instead of showing a stale rate
REFRESH_S = 0.25  # redraw at most this often
BAR_WIDTH = 16
MAX_FLOWS = 10  # busiest source → destination pairs shown
DISCOVERY_TIMEOUT = 5.0


class MonitorError(Exception):
    """What the user must fix or know (unreachable endpoint, no or several simulations): one line."""

    def __init__(self, message: str, status: int = EXIT_USAGE) -> None:
        super().__init__(message)
        self.status = status


def say(message: str) -> None:
    """One plain line on stderr (stdout carries the dashboard or the JSON records)."""
    print(f"monitor: {message}", file=sys.stderr, flush=True)


# ----- the bus side -----

@dataclass(frozen=True, slots=True)
class SimInfo:
    sim_id: str
    scenario: str | None = None  # None when its …/session query does not answer
    dt: float | None = None

    def label(self) -> str:
        return f"{self.sim_id} ({self.scenario})" if self.scenario else self.sim_id


class BusMonitor:
    """A session on a bus that finds simulations and follows one of them, subscribing only.

    ``where`` names the bus in messages: the Zenoh endpoint, or "the in-process bus"."""

    def __init__(self, transport: Transport, where: str, prefix: str = DEFAULT_PREFIX) -> None:
        self.transport = transport
        self.where = where
        self.prefix = prefix

    @classmethod
    def connect(cls, endpoint: str, prefix: str = DEFAULT_PREFIX, security: Security | None = None,
                settings: dict[str, Any] | None = None) -> BusMonitor:
        """A Zenoh client session to the router at ``endpoint``."""
        try:
            return cls(ZenohTransport.reach(endpoint, security, settings), endpoint, prefix)
        except TransportError as exc:
            raise MonitorError(str(exc)) from None

    def discover(self, timeout: float = DISCOVERY_TIMEOUT) -> list[SimInfo]:
        """Running simulations: the holders of ``{prefix}/<id>/alive/orchestrator`` tokens, by id."""
        tokens = self.transport.tokens(f"{self.prefix}/*/alive/{ORCHESTRATOR}", timeout)
        ids = {key[len(self.prefix) + 1:].split("/", 1)[0] for key in tokens}
        return [self.describe(sim_id) for sim_id in sorted(ids)]

    def describe(self, sim_id: str, timeout: float = DISCOVERY_TIMEOUT) -> SimInfo:
        """Scenario name and dt from ``…/session``; an orchestrator that does not answer stays anonymous."""
        try:
            info = self.transport.request(Keys(sim_id, self.prefix).session(), {"type": "session?"}, timeout)
        except (TransportError, CodecError):
            return SimInfo(sim_id)
        scenario = info.get("scenario") or {}
        return SimInfo(sim_id, scenario.get("name"), scenario.get("dt"))

    def follow(self, sim_id: str, on_metrics: Handler, on_alive: TokenHandler, on_offload: Handler | None = None
               ) -> None:
        """Subscribe to one simulation; handlers run in ``dispatch``. Offload events are asked for only
        when wanted: node processes build events only while someone subscribes to them."""
        keys = Keys(sim_id, self.prefix)
        self.transport.subscribe(keys.metrics(), on_metrics)
        if on_offload is not None:
            self.transport.subscribe(keys.events("offloaded"), on_offload)
        self.transport.watch_tokens(keys.alive(ORCHESTRATOR), on_alive)

    def dispatch(self, until: Callable[[], bool], idle: Callable[[], None] | None = None,
                 timeout: float | None = None) -> None:
        try:
            self.transport.dispatch(until=until, idle=idle, timeout=timeout)
        except CodecError as exc:
            raise MonitorError(f"cannot read the bus: {exc}", EXIT_FAILED) from None

    def close(self) -> None:
        self.transport.close()


def choose(found: list[SimInfo], wanted: str | None, endpoint: str) -> SimInfo:
    """The simulation to follow among those found behind ``endpoint``."""
    if wanted is not None:
        for info in found:
            if info.sim_id == wanted:
                return info
        running = ", ".join(i.label() for i in found) or "none"
        raise MonitorError(f"no simulation {wanted!r} at {endpoint} (running: {running})")
    if not found:
        raise MonitorError(f"no simulation running at {endpoint}; start one with `orchestrator launch SCENARIO "
                           "--serve`, or check --connect and --prefix")
    if len(found) > 1:
        raise MonitorError(f"{len(found)} simulations at {endpoint}: {', '.join(i.label() for i in found)}; "
                           "choose one with --sim ID")
    return found[0]


def launched_here(wanted: str | None) -> local_sims.Entry:
    """Without --connect: the simulation launched on this host (the only one, or --sim)."""
    try:
        entries = local_sims.running()
    except local_sims.LocalSimsError as exc:
        raise MonitorError(str(exc)) from None
    listing = "".join(f"\n  {e.describe()}" for e in entries)
    if wanted is not None:
        entries = [e for e in entries if e.sim == wanted]
        if not entries:
            raise MonitorError(f"no simulation {wanted!r} launched on this host (give --connect ENDPOINT for "
                               f"another host); running here:{listing or ' none'}")
        if len(entries) > 1:
            raise MonitorError(f"{len(entries)} simulations {wanted!r} on this host; choose one with --connect "
                               f"ENDPOINT:{listing}")
    elif not entries:
        raise MonitorError("no simulation running on this host; start one with `orchestrator launch SCENARIO "
                           "--serve`, or give --connect ENDPOINT to watch one on another host")
    elif len(entries) > 1:
        raise MonitorError(f"{len(entries)} simulations running on this host; choose one with --sim ID (or "
                           f"--connect ENDPOINT):{listing}")
    return entries[0]


# ----- the dashboard's state -----

@dataclass
class DashboardState:
    """What the dashboard shows, folded from the messages received so far.

    Rates and flows cover recent windows, so they describe the run now rather than since attaching.
    Wall times (``now``) are passed in, which keeps the state and ``render`` deterministic in tests.
    """

    sim_id: str
    scenario: str | None = None
    dt: float = 1.0
    record: dict[str, Any] | None = None  # the last …/metrics/tick message
    last_at: float = 0.0  # wall time it arrived
    missed: int = 0  # ticks whose message never came (best effort), this episode
    arrivals: deque[tuple[float, int]] = field(default_factory=deque)  # (wall time, tick), RATE_WINDOW_S
    deltas: deque[dict[str, int]] = field(default_factory=lambda: deque(maxlen=WINDOW_TICKS))  # records' "delta"
    shares: deque[dict[str, list[float]]] = field(  # each tick's per-node shares (utilisation), by key
        default_factory=lambda: deque(maxlen=WINDOW_TICKS))
    samples: dict[str, deque[float]] = field(default_factory=dict)  # recent samples (response times), by key
    offloads: deque[tuple[int, int, str, str]] = field(default_factory=deque)  # (episode, tick, from, to)

    def add_metrics(self, msg: dict[str, Any], now: float) -> None:
        last = self.record
        if last is not None and msg["episode"] != last["episode"]:
            self.missed = 0
            for window in (self.arrivals, self.deltas, self.shares, *self.samples.values()):
                window.clear()
        elif last is not None and msg["tick"] > last["tick"] + 1:
            self.missed += msg["tick"] - last["tick"] - 1
        if msg["tick"] > 0:
            self.dt = msg["time_s"] / msg["tick"]
        self.record = msg
        self.last_at = now
        self.arrivals.append((now, msg["tick"]))
        while self.arrivals[0][0] < now - RATE_WINDOW_S:
            self.arrivals.popleft()
        self.deltas.append(msg["delta"])
        nodes = msg["nodes"]
        self.shares.append({m.key(Out.BUS_NODES): nodes[m.key(Out.BUS_NODES)] for m in monitored(Out.BUS_NODES)
                            if m.agg is Agg.SHARE})
        for m in monitored(Out.BUS):
            if m.agg is Agg.SAMPLES:
                self.samples.setdefault(m.key(Out.BUS), deque(maxlen=RT_WINDOW)).extend(msg[m.key(Out.BUS)])
        while self.offloads and self._stale(self.offloads[0]):
            self.offloads.popleft()

    def add_offload(self, event: dict[str, Any]) -> None:
        self.offloads.append((event["episode"], event["tick"], event["node"], event["to"]))

    def _stale(self, offload: tuple[int, int, str, str]) -> bool:
        rec = self.record
        return rec is not None and (offload[0] < rec["episode"] or offload[1] <= rec["tick"] - WINDOW_TICKS)

    # ----- derived views -----

    def tick_rate(self) -> float | None:
        """Ticks per wall second over the last few seconds, as measured here."""
        if len(self.arrivals) < 2:
            return None
        (t0, k0), (t1, k1) = self.arrivals[0], self.arrivals[-1]
        return (k1 - k0) / (t1 - t0) if t1 > t0 else None

    def rates(self) -> dict[str, float]:
        """Each change the record's "delta" carries (tasks generated, completed, ...) per simulated second
        over the recent ticks."""
        seconds = len(self.deltas) * self.dt
        jobs = self.record is not None and carries_jobs(self.record)
        return {key: sum(d[key] for d in self.deltas) / seconds if seconds else 0.0
                for key in (m.key(Out.BUS_DELTA) for m in monitored(Out.BUS_DELTA, jobs))}

    def percentiles(self, key: str) -> tuple[float, float] | None:
        """p50 and p95 of the recent samples of ``key`` (response times, in seconds)."""
        window = self.samples.get(key)
        if not window:
            return None
        p50, p95 = np.percentile(np.fromiter(window, float), [50, 95])
        return float(p50), float(p95)

    def mean_shares(self) -> dict[str, list[float]]:
        """Per-node shares (utilisation) averaged over the recent ticks, by key."""
        if not self.shares:
            return {}
        return {key: np.mean(np.array([s[key] for s in self.shares]), axis=0).tolist() for key in self.shares[-1]}

    def flows(self) -> list[tuple[str, str, int]]:
        """Offloads (from, to, tasks) over the recent ticks, busiest first."""
        counts = Counter((o[2], o[3]) for o in self.offloads if not self._stale(o))
        return [(src, dst, n) for (src, dst), n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))]


# ----- rendering (pure) -----

def queue_bar(occupancy: int, buffer: int, width: int = BAR_WIDTH) -> Text:
    """occupancy / buffer as a bar: green, yellow from half full, red when full."""
    if buffer <= 0:
        return Text("-", style="dim")
    frac = min(occupancy, buffer) / buffer
    filled = round(frac * width)
    colour = "red" if occupancy >= buffer else "yellow" if frac >= 0.5 else "green"
    return Text.assemble(("█" * filled, colour), ("░" * (width - filled), "dim"))


def _num(x: float) -> str:
    return f"{x:.3g}" if abs(x) < 1000 else f"{x:,.0f}"


def monitored(out: Out, jobs: bool = False) -> list[Metric]:
    """The catalogue's metrics that the dashboard shows, of those ``out`` (a part of the record) carries; the
    job metrics with ``jobs`` (the record is of a scenario of jobs, ``carries_jobs``)."""
    return [m for m in shown(out, jobs) if Out.MONITOR in m.show]


def carries_jobs(record: dict[str, Any]) -> bool:
    """A record of a scenario of jobs: its totals carry the job metrics (docs/bus.md)."""
    return METRIC["jobs"].key(Out.BUS) in record["totals"]


def breakdown(m: Metric, totals: dict[str, Any]) -> str:
    """A metric with parts as "total = part v + part v ...", from the record's totals."""
    key = m.key(Out.BUS)
    if m.form(Out.BUS) is Form.PARTS:
        parts = totals[key]
        whole = sum(parts.values())
    else:
        parts = {p.key: totals[f"{key}_{p.key}"] for p in m.parts if f"{key}_{p.key}" in totals}
        whole = totals[key]
    return f"{quantity(whole, m.unit)} = " + " + ".join(f"{p.label} {quantity(parts[p.key], m.unit)}"
                                                        for p in m.parts if p.key in parts)


def _percentiles(state: DashboardState, m: Metric, totals: dict[str, Any]) -> str:
    """p50 and p95 of the recent samples of ``m`` (one per completion), or why there are none."""
    pct = state.percentiles(m.key(Out.BUS))
    if pct is not None:
        return (f"p50 {quantity(pct[0], m.unit)}  p95 {quantity(pct[1], m.unit)}  "
                f"(last {len(state.samples[m.key(Out.BUS)])} completions)")
    completed = totals.get(METRIC["completed"].key(Out.BUS), 0)
    if completed:  # the percentiles cover completions seen here; totals cover the episode
        return f"no completion since attaching ({completed} earlier in this episode)"
    return "no completion yet"


def render(state: DashboardState, now: float) -> RenderableType:
    """The whole dashboard for ``state`` at wall time ``now`` (fits 80 columns)."""
    rec = state.record
    title = Text.assemble(("ZenohEdge monitor", "bold"), " · sim ", (state.sim_id, "bold cyan"),
                          f" · {state.scenario or 'scenario unknown'}")
    if rec is None:
        return Group(title, Text("waiting for the first tick (a served simulation ticks while an episode runs)",
                                 style="dim"))
    tot, nodes = rec["totals"], rec["nodes"]
    idle = now - state.last_at
    rate = state.tick_rate()
    if idle > IDLE_S:
        pace = Text(f"no tick for {idle:.0f} s: episode over or paused", style="yellow")
    else:
        pace = Text("measuring ticks/s" if rate is None else f"{rate:.1f} ticks/s")
    rates, jobs = state.rates(), carries_jobs(rec)
    head = Table.grid(padding=(0, 2))
    head.add_column(style="bold", no_wrap=True)
    head.add_column()
    head.add_row("tick", Text.assemble(f"{rec['tick']} ({_num(rec['time_s'])} s simulated), episode "
                                       f"{rec['episode']} · ", pace))
    head.add_row("per sim s", "  ".join(f"{m.short} {rates[m.key(Out.BUS_DELTA)]:.2f}" for m in
                                        monitored(Out.BUS_DELTA, jobs)) + f"  (last {len(state.deltas)} ticks)")
    def values(chosen: list[Metric]) -> str:
        return "  ".join(f"{m.label} {quantity(tot[m.key(Out.BUS)], m.unit)}" for m in chosen)

    metrics = [m for m in monitored(Out.BUS, jobs) if not m.jobs]  # the jobs' own rows follow the episode's
    plain = [m for m in metrics if m.agg is Agg.COUNT and m.form(Out.BUS) is Form.TOTAL]
    head.add_row("totals", values(plain))
    for m in metrics:
        if m.form(Out.BUS) is not Form.TOTAL:
            head.add_row(m.label, breakdown(m, tot))
    head.add_row("now", "  ".join(f"{m.label} {quantity(tot[m.key(Out.BUS)], m.unit)}"
                                  + (f" of {len(nodes['id'])}" if m.unit == "nodes" else "")
                                  for m in metrics if m.agg is Agg.LEVEL))
    for m in metrics:
        if m.agg is Agg.SAMPLES:
            head.add_row(m.label, _percentiles(state, m, tot))
    ratios = [m for m in metrics if m.agg is Agg.RATIO]  # beside response time, so that drops are not hidden
    if ratios:
        head.add_row("episode", values(ratios))
    job_metrics = [m for m in monitored(Out.BUS, jobs) if m.jobs]  # a scenario of jobs: counts, then ratios
    if job_metrics:
        head.add_row("jobs", values([m for m in job_metrics if m.agg is Agg.COUNT]))
        head.add_row("jobs so far", values([m for m in job_metrics if m.agg is Agg.RATIO]))
    if state.missed:
        head.add_row("missed", Text(f"{state.missed} tick(s) lost on the way (best effort)", style="yellow"))

    counters = [m for m in monitored(Out.BUS_NODES) if m.agg is not Agg.LEVEL]
    averaged = [m.short for m in counters if m.agg is Agg.SHARE]
    table = Table(box=box.SIMPLE_HEAD, show_edge=False, padding=(0, 1), title_justify="left",
                  title=f"nodes ({', '.join(averaged)}: last {len(state.shares)} ticks)" if averaged else "nodes")
    for name, justify in (("node", "left"), ("queue", "left"), ("occ/buf", "right"), ("", "left"),
                          *((m.short, "right") for m in counters)):
        table.add_column(name, justify=justify, no_wrap=True)
    shares = state.mean_shares()
    for i, nid in enumerate(nodes["id"]):
        occ = nodes["queue"][i] + nodes["undecided"][i]
        buf = nodes["buffer"][i]
        table.add_row(nid, queue_bar(occ, buf), f"{occ}/{buf}",
                      Text("OVERLOAD", style="bold red") if nodes["overloaded"][i] else "",
                      *(f"{100 * shares[m.key(Out.BUS_NODES)][i]:.0f} %" if m.agg is Agg.SHARE
                        else quantity(nodes[m.key(Out.BUS_NODES)][i], m.unit) for m in counters))
    flows = state.flows()
    if flows:
        flow_view: RenderableType = Table(box=box.SIMPLE_HEAD, show_edge=False, padding=(0, 1))
        flow_view.add_column(f"offloads over the last {WINDOW_TICKS} ticks: from → to", no_wrap=True)
        flow_view.add_column("tasks", justify="right")
        for src, dst, n in flows[:MAX_FLOWS]:
            flow_view.add_row(f"{src} → {dst}", str(n))
        if len(flows) > MAX_FLOWS:
            flow_view.add_row(f"… {len(flows) - MAX_FLOWS} more", str(sum(n for *_, n in flows[MAX_FLOWS:])))
    else:
        flow_view = Text(f"no offload over the last {WINDOW_TICKS} ticks", style="dim")
    return Group(title, head, Text(), table, Text(), flow_view)


# ----- following one simulation -----

class Follower:
    """Feeds one simulation's messages to the JSON printer or the dashboard until it should stop."""

    def __init__(self, info: SimInfo, *, as_json: bool, once: bool, console: Console) -> None:
        self.info = info
        self.as_json = as_json
        self.once = once
        self.console = console
        self.state = DashboardState(info.sim_id, info.scenario, info.dt or 1.0)
        self.live: Live | None = None
        self.drawn = 0.0
        self.announced = False  # the orchestrator's token was seen since subscribing
        self.ended = False
        self.done = False  # --once: one snapshot given

    def on_metrics(self, key: str, msg: dict[str, Any]) -> None:
        if self.as_json:
            print(json.dumps(msg), flush=True)
        else:
            self.state.add_metrics(msg, time.monotonic())
            self.draw()
        self.done = self.once

    def on_offload(self, key: str, event: dict[str, Any]) -> None:
        self.state.add_offload(event)

    def on_alive(self, key: str, alive: bool) -> None:
        self.announced = self.announced or alive
        self.ended = self.ended or not alive

    def finished(self) -> bool:
        return self.done or self.ended

    def draw(self, force: bool = False) -> None:
        now = time.monotonic()
        if self.live is not None and (force or now - self.drawn >= REFRESH_S):
            self.drawn = now
            self.live.update(render(self.state, now), refresh=True)

    def run(self, bus: BusMonitor) -> None:
        """Subscribe, wait for the orchestrator's token, then feed the view until done, ended or Ctrl-C."""
        sim = self.info.sim_id
        bus.follow(sim, self.on_metrics, self.on_alive, None if self.as_json else self.on_offload)
        try:  # the token subscription's history says the orchestrator is (still) there
            bus.dispatch(lambda: self.announced or self.ended, timeout=DISCOVERY_TIMEOUT)
        except TimeoutError:  # it left between discovery and subscribing
            self.ended = True
            return
        say(f"attached to {self.info.label()} at {bus.where} (Ctrl-C to detach)")
        until = self.finished
        if self.as_json:
            bus.dispatch(until)
        elif self.once:
            bus.dispatch(until)
            self.console.print(render(self.state, time.monotonic()))
        else:
            with Live(render(self.state, time.monotonic()), console=self.console, auto_refresh=False) as live:
                self.live = live
                try:
                    bus.dispatch(until, idle=self.draw)
                finally:
                    self.draw(force=True)
                    self.live = None


def cmd_monitor(args: argparse.Namespace) -> int:
    """Find the simulation, follow it; every way out closes the session and says why in one line."""
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)  # SIGTERM ends it like Ctrl-C
    bus: BusMonitor | None = None
    sim = args.sim
    try:
        endpoint = args.connect
        if endpoint is None:
            entry = launched_here(sim)
            say(f"found on this host: {entry.describe()}")
            endpoint, sim = entry.endpoint, entry.sim
        try:
            security, settings = security_options(args)
        except SecurityError as exc:
            raise MonitorError(str(exc)) from None
        bus = BusMonitor.connect(endpoint, args.prefix, security, settings)
        info = choose(bus.discover(), sim, endpoint)
        sim = info.sim_id
        follower = Follower(info, as_json=args.json, once=args.once, console=Console(highlight=False))
        follower.run(bus)
        if follower.ended:
            say(f"simulation {sim} ended: its orchestrator left")
        return EXIT_OK
    except MonitorError as exc:
        say(str(exc))
        return exc.status
    except KeyboardInterrupt:
        say(f"detached from {sim}" if sim else "interrupted")
        return EXIT_OK
    except BrokenPipeError:  # `--json | head`: the reader has gone, which is a normal way to stop
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    finally:
        signal.signal(signal.SIGTERM, previous)
        if bus is not None:
            bus.close()


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """Register ``monitor`` on the subparsers of ``orchestrator``."""
    p = sub.add_parser("monitor", help="watch a running simulation live (it is never disturbed)",
                       description="Find the simulation launched on this host, or those running behind a Zenoh "
                                   "router (--connect), and follow one: a live "
                                   "dashboard (tick rate, task rates, response times, per-node queues, offload "
                                   "flows), or one JSON metrics record per tick. It only subscribes, so it can "
                                   "attach and detach at any time. Ends on Ctrl-C or when the simulation ends.")
    add_sim_options(p, required=False,
                    connect_help="the router of the simulation, as printed by `orchestrator launch`, e.g. "
                                 "tcp/10.0.0.1:7447 (default: the simulation launched on this host)",
                    sim_help="simulation id (default: the only one running)")
    p.add_argument("--json", action="store_true",
                   help="print each tick's metrics record as one line of JSON (schema in docs/bus.md)")
    p.add_argument("--once", action="store_true", help="print one snapshot at the next tick and exit")
    add_security_options(p, identity="monitor",
                         config_help="a Zenoh JSON5 configuration file merged last into the monitor's session "
                                     "configuration (its settings win)")
    p.set_defaults(func=cmd_monitor)
    return p


def main(argv: list[str] | None = None) -> int:
    """``python -m orchestrator.viewers.monitor``: the same command outside ``orchestrator``."""
    parser = argparse.ArgumentParser(prog="orchestrator")  # usage reads `orchestrator monitor ...`
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["monitor", *(sys.argv[1:] if argv is None else argv)])
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
