"""A host's side of the clock protocol (docs/protocol.md), over any transport.

Per tick t it takes part in: wait for ``Tick(t)``; wait until the publications sent to this process
since it last ran (in tick t - 1, and mail held for it in the ticks it slept through) number
``expect[self]``; deliver them; run the roles; publish the outgoing batches, then ``Done``. Ticks in which
it has neither mail nor work due never reach it.
Publications can overtake the tick that announces them, or belong to an episode this process has
not started yet, so they are buffered by (episode, sent tick) until their turn.

Anyone on the bus can publish on this process's keys, so what cannot be trusted is refused, counted
and logged (docs/bus.md, "Rejected messages"): a tick without the clock's MAC (``origin``), or of an
epoch older than the newest it has seen (a holder of the clock whose claim is over), a tick of another
episode or one already run, mail from a process that never sends here or for roles that are not here, a
task of a task type the scenario does not have, mail that comes after its tick ran, a second batch from
the same sender on the same key in one tick, a tick that gives this process nothing to do or skips the
tick it has work due in. Mail that passes every check
but outnumbers what the clock announced, or differs from a batch the same sender already sent on the
same key in the same tick, cannot be told from the genuine mail: the process then stops with an error
rather than run with it. Its reports are sealed with its own key of the tick's epoch.
"""

from __future__ import annotations

from collections import defaultdict

from node_runtime.model.messages import Kind
from node_runtime.runtime.failure import account
from node_runtime.runtime.host import Host
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.origin import Keyring, authentic
from node_runtime.runtime.protocol import Batch, Done, Tick
from node_runtime.runtime.rejections import BAD_MAC, STALE_EPOCH, UNKNOWN_SENDER, WRONG_SHAPE, WRONG_TICK
from node_runtime.runtime.transport import Monitored, Transport


class HostDriver:
    def __init__(self, host: Host, transport: Transport, keys: Keys, keyring: Keyring,
                 done_key: str | None = None) -> None:
        """``keyring``: the clock's key and this process's own; ``done_key``: where to report, when not to the
        clock itself (a host's aggregator)."""
        self.host = host
        self.transport = transport
        self.keys = keys
        self.keyring = keyring
        self.proc = host.proc
        self.epoch = 0  # the newest epoch of the clock seen in a tick it sealed
        plan = host.plan
        self.proc_index = plan.proc_index[host.proc]
        self.episode = -1
        self.tick = -1  # the last tick run in this episode
        self.wake: int | None = None  # the next tick with work due, as the last Done told the clock
        self.pending: Tick | None = None
        self.stopped = False
        self.failed: str | None = None
        self.conflict: str | None = None  # two different batches came from one sender in one tick: fail in the next
        # (episode, sent tick) -> {(sending process, key): its batch}: one per sender and key in a tick
        self.buffer: defaultdict[tuple[int, int], dict[tuple[str, str], Batch]] = defaultdict(dict)
        self.rejections = transport.rejections
        self.rejections.who = self.proc
        # who may publish to this process, and where the envelopes they carry may go
        self.senders = frozenset(p for p, them in plan.recipients.items() if self.proc in them)
        self.hosted = frozenset(host.by_id)
        self.proc_of = plan.proc_of
        self.publications = plan.publications  # role -> the topics it broadcasts on
        self.n_roles = len(plan.roles)
        self.n_types = len(plan.scenario.workload.task_types)  # a task's type indexes them
        # one detector per node covers every event kind, users' own included; publishers come lazily
        self.listeners = [transport.monitored(keys.events("*", node)) for node in host.nodes]
        self.monitors: dict[tuple[str, str], Monitored] = {}
        # the keys this process publishes on, built once rather than every tick
        self.done_key = done_key or keys.done(self.proc)
        self.inbox_keys = {p: keys.inbox(p) for p in plan.destinations(self.proc)}
        self.broadcast_key = keys.broadcasts(self.proc) if plan.listeners[self.proc] else None
        transport.subscribe(keys.tick(), self.on_tick)
        transport.subscribe(keys.tick(self.proc), self.on_tick)
        transport.subscribe(keys.inbox(self.proc), self.on_batch)
        for proc in plan.broadcasters[self.proc]:
            transport.subscribe(keys.broadcasts(proc), self.on_batch)

    def on_tick(self, key: str, cmd: Tick) -> None:
        if type(cmd) is not Tick:
            self.rejections.add(key, WRONG_SHAPE, f"a {type(cmd).__name__} where a tick was expected")
            return
        if not authentic(self.keyring.clock_key(cmd.epoch), cmd):
            self.rejections.add(key, BAD_MAC, f"a {cmd.command} tick {cmd.tick} without the clock's MAC")
            return
        if cmd.epoch < self.epoch:
            self.rejections.add(key, STALE_EPOCH, f"a {cmd.command} tick {cmd.tick} of epoch {cmd.epoch}; the clock "
                                                  f"is in epoch {self.epoch}")
            return
        self.epoch = cmd.epoch
        if cmd.command == "fence":
            return
        if cmd.command == "stop":
            self.stopped = True
            return
        why = self.unexpected(cmd)
        if why is not None:
            self.rejections.add(key, WRONG_TICK, why)
            return
        self.pending = cmd
        self.advance()

    def unexpected(self, cmd: Tick) -> str | None:
        """Why the clock cannot have sent this tick to this process, or None. It opens a tick for a
        process only with mail announced, actions for its roles, or work due; it never skips work due."""
        if cmd.command == "reset":  # episode numbers only grow, whoever drives the clock
            if cmd.episode > self.episode and not cmd.states:
                return None
            return f"a reset to episode {cmd.episode}; this process is in episode {self.episode}"
        t, wake, host = cmd.tick, self.wake, self.host
        for w, (*_, sent, _) in cmd.states.items():  # workers heard here whose states come as mail are not in it
            if w >= self.n_roles or sent >= t or (w in host.states_heard and w not in host.states_from_clock):
                return f"tick {t} with a state of role {w} sent in tick {sent}, which cannot come with this tick"
        if cmd.episode != self.episode or t <= self.tick:
            return f"tick {t} of episode {cmd.episode}; this process ran tick {self.tick} of episode {self.episode}"
        if self.pending is not None:
            return f"tick {t} while tick {self.pending.tick} waits for its mail"
        if wake is not None and t > max(wake, self.tick + 1):
            return f"tick {t}; this process has work due in tick {wake}, which the clock would not skip"
        if not ((wake is not None and wake <= t) or cmd.expect.get(self.proc_index, 0) > 0
                or not self.hosted.isdisjoint(cmd.actions)):
            return f"tick {t} with nothing for this process: no mail announced, no action, no work due"
        return None

    def on_batch(self, key: str, batch: Batch) -> None:
        if type(batch) is not Batch:
            self.rejections.add(key, WRONG_SHAPE, f"a {type(batch).__name__} where a batch was expected")
            return
        if batch.src == self.proc or batch.episode < self.episode:  # our own broadcast; mail of a finished episode
            return
        why = self.untrusted(batch)
        if why is not None:
            self.rejections.add(key, *why)
            return
        slot = self.buffer[(batch.episode, batch.tick)]
        first = slot.get((batch.src, key))
        if first is not None:
            self.rejections.add(key, WRONG_TICK, f"a second batch from {batch.src} sent in tick {batch.tick}")
            if first != batch and self.conflict is None:  # one of them is forged, and nothing tells which
                self.conflict = (f"received two different batches from {batch.src} sent in tick {batch.tick}: "
                                 "another publisher is on the bus (see the rejected-message log)")
            return
        slot[(batch.src, key)] = batch
        self.advance()

    def untrusted(self, batch: Batch) -> tuple[str, str] | None:
        """Why a batch cannot be this process's mail (reason, detail), or None."""
        if batch.src not in self.senders:
            return UNKNOWN_SENDER, f"process {batch.src!r} never sends to {self.proc}"
        if batch.episode > self.episode + 1 or (batch.episode == self.episode and batch.tick < self.tick):
            return WRONG_TICK, (f"sent in tick {batch.tick} of episode {batch.episode}; this process ran tick "
                                f"{self.tick} of episode {self.episode}")
        proc_of = self.proc_of
        for env in batch.envelopes:
            if env.dst not in self.hosted and not (env.kind is Kind.STATE
                                                   and env.dst in self.publications.get(env.src, ())):
                return UNKNOWN_SENDER, f"an envelope for {env.dst!r}, which is neither here nor its sender's topic"
            if proc_of.get(env.src) != batch.src:
                return UNKNOWN_SENDER, f"an envelope from {env.src!r}, which {batch.src} does not host"
            if env.arrive <= batch.tick:
                return WRONG_TICK, f"an envelope sent in tick {batch.tick} that arrives at tick {env.arrive}"
            if env.kind is Kind.TASK and env.body.type is not None and not 0 <= env.body.type < self.n_types:
                return WRONG_SHAPE, f"a task of type {env.body.type}; the scenario has {self.n_types} task types"
        return None

    def advance(self) -> None:
        cmd = self.pending
        if cmd is None or self.failed:
            return
        if self.conflict is not None:
            self.pending = None
            self.fail(cmd, self.conflict)
            return
        if cmd.command == "reset":
            self.pending = None
            for key in [k for k in self.buffer if k[0] < cmd.episode]:
                del self.buffer[key]
            self.episode = cmd.episode
            self.host.reset(cmd.episode, cmd.seed, frozenset(cmd.external), cmd.policy)
            self.run(cmd)
            return
        # what was sent since the last run (batches sent before it were refused on arrival)
        due = sorted(k for k in self.buffer if k[0] == self.episode and k[1] < cmd.tick)
        arrived = sum(len(self.buffer[k]) for k in due)
        expected = cmd.expect.get(self.proc_index, 0)
        if arrived < expected:
            return
        self.pending = None
        if arrived > expected:
            self.fail(cmd, f"received {arrived} publications sent since tick {self.tick}, {expected} "
                                "announced: another publisher is on the bus (see the rejected-message log)")
            return
        for key in due:
            for batch in self.buffer.pop(key).values():
                self.host.deliver(batch.envelopes)
        if cmd.states:
            self.host.take_states(cmd.states)
        self.run(cmd)

    def fail(self, cmd: Tick, why: str) -> None:
        """Report a failure in tick ``cmd``, then stop: the orchestrator names this process and shows ``why``."""
        self.failed = why
        self.transport.publish(self.done_key, Done(self.proc, self.episode, cmd.tick, {}, {}, error=why,
                                                   epoch=cmd.epoch), self.keyring.proc_key(self.proc, cmd.epoch))

    def run(self, cmd: Tick) -> None:
        t = self.tick = cmd.tick
        self.host.events_on = any(m.listened for m in self.listeners)
        try:
            out = self.host.run(t, cmd.actions)
        except Exception as exc:
            self.fail(cmd, account(exc))
            return
        done = out.done
        done.epoch = cmd.epoch
        self.wake = done.wake
        if self.rejections.changed:  # rare: only after something was refused
            self.rejections.changed = False
            done.rejected = dict(self.rejections.counts)
        for proc, envelopes in out.batches.items():
            self.transport.publish(self.inbox_keys[proc], Batch(self.episode, t, self.proc, envelopes))
        if out.broadcasts:
            self.transport.publish(self.broadcast_key, Batch(self.episode, t, self.proc, out.broadcasts))
        self.transport.publish(self.done_key, done, self.keyring.proc_key(self.proc, cmd.epoch))
        for kind, node, fields in out.events:  # best effort: monitors never slow the emulation down
            monitor = self.monitors.get((kind, node))
            fresh = monitor is None  # a new publisher may not have heard of its subscribers yet
            if fresh:
                monitor = self.monitors[(kind, node)] = self.transport.monitored(self.keys.events(kind, node))
            if fresh or monitor.listened:
                monitor.put({"type": "event", "kind": kind, "node": node, "episode": self.episode, "tick": t,
                             **fields})
