"""One host's ``Done`` reports, forwarded to the orchestrator as one message a tick (docs/protocol.md,
"Several hosts").

``zenohedge-node`` runs it in its own session, on the router its processes connect to. Those processes
publish their ``Done`` on ``…/host/<group>/done/<proc>``, which only this host listens to; the aggregator
forwards the reports of a tick together, as ``Dones`` on ``…/clock/dones/<group>``, once every local
process the tick was opened for has reported. So the orchestrator handles one message per host and tick
instead of one per process: what matters when a host runs hundreds of processes.

It learns which processes a tick was opened for from the ticks themselves: it hears the same
``…/clock/tick`` and ``…/clock/tick/<proc>`` publications as its processes. Nothing orders those against
the processes' reports, so a report can arrive before the aggregator knows its tick, or after it forwarded
the others: it then travels in a batch of its own. A report is never held for a process that may never
report either: a failure (a ``Done`` with an error) goes at once, and whatever waits is forwarded when
the bus has been quiet for a moment (``flush``), so the orchestrator blames only the silent. The
orchestrator checks each report in a batch as if it had come alone.

Proof of origin (``origin``): the aggregator takes only reports that carry their process's MAC, and seals
what it forwards with the host's own key, which is what the orchestrator checks; it takes only the ticks
that carry the clock's. A second report of a process for one tick is never merged into the first: the first
goes on at once, so that the orchestrator sees both and judges.

A host that has forwarded nothing for ``BEAT_S`` sends an empty batch, sealed like any other: the
orchestrator then tells a host that stood still or was cut off (nothing from it, not even that) from a
stopped process (its host still beats). By its reports alone, a host stopped between two batches of one
tick would look like its unforwarded process stopped.
"""

from __future__ import annotations

import time

from node_runtime.runtime.keys import Keys
from node_runtime.runtime.origin import Keyring, authentic
from node_runtime.runtime.protocol import Done, Dones, Tick
from node_runtime.runtime.rejections import BAD_MAC, UNKNOWN_SENDER, WRONG_SHAPE
from node_runtime.runtime.transport import Transport

TickId = tuple[int, int]  # (episode, tick)
BEAT_S = 0.25  # the longest a host stays silent while it runs (an empty batch says it is there)


class DoneAggregator:
    def __init__(self, transport: Transport, keys: Keys, group: str, procs: list[str], keyring: Keyring) -> None:
        """``keyring``: the clock's key, the processes' and the host's own (``Server._register``)."""
        self.transport = transport
        self.keyring = keyring
        self.epoch = 0  # the newest epoch of the clock heard
        self.group = group
        self.procs = frozenset(procs)
        self.report_keys = {keys.host_done(group, p): p for p in procs}
        self.out_key = keys.dones(group)
        self.opened: dict[TickId, set[str]] = {}  # the local processes each tick was opened for, as heard
        self.reports: dict[TickId, dict[str, Done]] = {}  # reports not yet forwarded
        self.sent: dict[TickId, set[str]] = {}  # the processes whose reports of a tick went on: a tick heard after
        # them waits for them no more (or only a quiet bus, which a flood of refused messages never is, would)
        self.rejections = transport.rejections
        self.last_sent = time.monotonic()  # when anything last went to the orchestrator
        self.tick_keys = {keys.tick(p): p for p in procs}
        transport.subscribe(keys.tick(), self.on_tick)
        for key in self.tick_keys:
            transport.subscribe(key, self.on_tick)
        transport.subscribe(keys.host_done(group), self.on_done)

    def on_tick(self, key: str, cmd: Tick) -> None:
        if type(cmd) is not Tick or not authentic(self.keyring.clock_key(cmd.epoch), cmd) or cmd.epoch < self.epoch:
            return  # the processes refuse and count a bad tick
        self.epoch = cmd.epoch
        if cmd.command in ("stop", "fence"):
            return
        tick = (cmd.episode, cmd.tick)
        for old in [t for t in self.reports if t < tick]:  # the clock moved on: nobody still waits for these
            self.forward(old)
        for old in [t for t in self.opened if t < tick]:
            del self.opened[old]
        for old in [t for t in self.sent if t < tick]:
            del self.sent[old]
        proc = self.tick_keys.get(key)
        opened = self.procs if proc is None else {proc}
        self.opened.setdefault(tick, set()).update(opened - self.sent.get(tick, set()))
        self.maybe_forward(tick)
        self.beat()

    def on_done(self, key: str, done: Done) -> None:
        if type(done) is not Done:
            self.rejections.add(key, WRONG_SHAPE, f"a {type(done).__name__} where a done was expected")
            return
        if self.report_keys.get(key) != done.proc:
            self.rejections.add(key, UNKNOWN_SENDER, f"a done of {done.proc!r}, which does not publish on this key")
            return
        if not authentic(self.keyring.proc_key(done.proc, done.epoch), done):
            self.rejections.add(key, BAD_MAC, f"a done of {done.proc} for tick {done.tick} without its MAC")
            return
        tick = (done.episode, done.tick)
        if done.proc in self.reports.get(tick, ()):  # a second one: both go on, and the orchestrator judges
            self.forward(tick)
        self.reports.setdefault(tick, {})[done.proc] = done
        if done.error is not None:
            self.forward(tick)
        else:
            self.maybe_forward(tick)

    def maybe_forward(self, tick: TickId) -> None:
        """Forward a tick's reports once every process it was opened for, as far as known, has reported."""
        reports = self.reports.get(tick)
        if reports and self.opened.get(tick, set()).issubset(reports):
            self.forward(tick)

    def forward(self, tick: TickId) -> None:
        reports = self.reports.pop(tick, None)
        if reports:
            opened = self.opened.get(tick)
            if opened is not None:
                opened.difference_update(reports)
            self.sent.setdefault(tick, set()).update(reports)
            for epoch in sorted({d.epoch for d in reports.values()}):  # one epoch a tick, but for a forgery
                self._publish(Dones(self.group, [d for d in reports.values() if d.epoch == epoch], epoch))

    def _publish(self, dones: Dones) -> None:
        self.transport.publish(self.out_key, dones, self.keyring.host_key(self.group, dones.epoch))
        self.last_sent = time.monotonic()

    def flush(self) -> None:
        """Forward everything waiting: the bus is quiet, so a process the reports wait for may be hung."""
        for tick in list(self.reports):
            self.forward(tick)
        self.beat()

    def beat(self) -> None:
        """An empty batch, if nothing went to the orchestrator for ``BEAT_S``: this host is still there."""
        if time.monotonic() - self.last_sent >= BEAT_S:
            self._publish(Dones(self.group, [], self.epoch))
