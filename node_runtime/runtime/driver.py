"""A host's side of the clock protocol (docs/protocol.md), over any transport.

Per tick t it takes part in: wait for ``Tick(t)``; wait until the publications sent to this process
in tick t - 1 number ``expect[self]``; deliver them; run the roles; publish the outgoing batches, then
``Done``. Ticks in which it has neither mail nor work due never reach it.
Publications can overtake the tick that announces them, or belong to an episode this process has
not started yet, so they are buffered by (episode, sent tick) until their turn.
"""

from __future__ import annotations

import traceback
from collections import defaultdict

from node_runtime.runtime.host import Host
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.protocol import Batch, Done, Tick
from node_runtime.runtime.transport import Monitored, Transport


class HostDriver:
    def __init__(self, host: Host, transport: Transport, keys: Keys) -> None:
        self.host = host
        self.transport = transport
        self.keys = keys
        self.proc = host.proc
        self.proc_index = host.plan.proc_index[host.proc]
        self.episode = -1
        self.pending: Tick | None = None
        self.stopped = False
        self.failed: str | None = None
        self.buffer: defaultdict[tuple[int, int], list[Batch]] = defaultdict(list)
        # one detector per node covers every event kind, users' own included; publishers come lazily
        self.listeners = [transport.monitored(keys.events("*", node)) for node in host.nodes]
        self.monitors: dict[tuple[str, str], Monitored] = {}
        # the keys this process publishes on, built once rather than every tick
        self.done_key = keys.done(self.proc)
        self.inbox_keys = {p: keys.inbox(p) for p in host.plan.destinations(self.proc)}
        self.topic_keys = {topic: keys.topic(topic) for topic in host.published_topics()}
        transport.subscribe(keys.tick(), self.on_tick)
        transport.subscribe(keys.tick(self.proc), self.on_tick)
        transport.subscribe(keys.inbox(self.proc), self.on_batch)
        for topic in host.plan.topics_of(self.proc):
            transport.subscribe(keys.topic(topic), self.on_batch)

    def on_tick(self, key: str, cmd: Tick) -> None:
        if cmd.command == "stop":
            self.stopped = True
            return
        self.pending = cmd
        self.advance()

    def on_batch(self, key: str, batch: Batch) -> None:
        if batch.src == self.proc or batch.episode < self.episode:
            return
        self.buffer[(batch.episode, batch.tick)].append(batch)
        self.advance()

    def advance(self) -> None:
        cmd = self.pending
        if cmd is None or self.failed:
            return
        if cmd.command == "reset":
            self.pending = None
            for key in [k for k in self.buffer if k[0] < cmd.episode]:
                del self.buffer[key]
            self.episode = cmd.episode
            self.host.reset(cmd.episode, cmd.seed, frozenset(cmd.external), cmd.policy)
            self.run(cmd)
            return
        arrived = self.buffer.get((self.episode, cmd.tick - 1), ())
        if len(arrived) < cmd.expect.get(self.proc_index, 0):
            return
        self.pending = None
        for key in sorted(k for k in self.buffer if k[0] == self.episode and k[1] < cmd.tick):
            for batch in self.buffer.pop(key):
                self.host.deliver(batch.envelopes)
        self.run(cmd)

    def run(self, cmd: Tick) -> None:
        t = cmd.tick
        self.host.events_on = any(m.listened for m in self.listeners)
        try:
            out = self.host.run(t, cmd.actions)
        except Exception as exc:  # report, then stop: the orchestrator names this process
            self.failed = f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"
            self.transport.publish(self.done_key, Done(self.proc, self.episode, t, {}, {}, error=self.failed))
            return
        for proc, envelopes in out.batches.items():
            self.transport.publish(self.inbox_keys[proc], Batch(self.episode, t, self.proc, envelopes))
        for topic, envelopes in out.topics.items():
            self.transport.publish(self.topic_keys[topic], Batch(self.episode, t, self.proc, envelopes))
        self.transport.publish(self.done_key, out.done)
        for kind, node, fields in out.events:  # best effort: monitors never slow the emulation down
            monitor = self.monitors.get((kind, node))
            fresh = monitor is None  # a new publisher may not have heard of its subscribers yet
            if fresh:
                monitor = self.monitors[(kind, node)] = self.transport.monitored(self.keys.events(kind, node))
            if fresh or monitor.listened:
                monitor.put({"type": "event", "kind": kind, "node": node, "episode": self.episode, "tick": t,
                             **fields})
