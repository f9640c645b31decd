"""The simulated clock: the orchestrator's side of the barrier protocol (docs/protocol.md).

``step`` opens tick t with ``Tick(t, expect)``, where ``expect[p]`` is the number of publications
the processes reported sending to ``p`` in tick t - 1, and returns once every process it opened the
tick for has reported ``Done(t)``. It opens it only for the processes that have mail from tick t - 1
or said in their last ``Done`` that they have work at t: the others sleep, and their last reports
stand. Mail a process may hold (``Done.held``: it arrives later, or is broadcasts its roles hold) wakes
nobody before it is due: it is added to the count of the next tick its process runs, which comes at the
latest when it is due or once ``HOLD_LIMIT`` publications wait. A reset opens tick 0 for all. A process
that reports an error, dies, or stays silent past the timeout ends the run with an error that names it
and the nodes it hosted; silent processes on a host from which nothing came for half the timeout (a
``zenohedge-node`` beats while it runs) are blamed on that host, by its group.

A driver that gives actions (the environment) may open the next tick ahead (``open_next``) for the
processes that cannot get any, so that they run while its agents decide; ``step`` then opens it for the
rest and collects every report. A reset first collects the reports of a tick opened ahead.

A host that runs several processes (``zenohedge-node``) may forward their reports of a tick together,
as one ``Dones`` message on ``…/clock/dones/<group>``; each report in it is checked as if it had come alone
on its process's key, and only processes placed in that group may report there.

Anyone on the bus can publish on ``…/clock/done/*``, so a ``Done`` counts only if it comes on the key
of a process the tick was opened for (or its host's), names that process, carries that process's MAC (or
its host's, over a host's message) of the clock's epoch (``origin``), is for the current episode and tick,
and reports only on the roles the process hosts and the processes it may send to. Anything else is
refused, counted and logged (docs/bus.md, "Rejected messages"); an error in a refused ``Done`` ends
nothing. A second report of a process for a tick it already reported is refused when it is a copy of the
first (a replay); when it differs, both carry the process's MAC, so its key is in other hands and nothing
tells which is true: the run ends with an error that names the process.

The clock is held in an *epoch*: the orchestrator's own, or one driver's claim (``serve.py``). Its ticks
carry the epoch and its MAC of that epoch, and node processes refuse ticks of an epoch older than the
newest they have seen (``fence`` tells them of a new one when nobody ticks).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection, Sequence
from typing import Any

from node_runtime.model.role import role_node, state_topic
from node_runtime.runtime.host import states_by_clock
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.origin import Keyring, authentic
from node_runtime.runtime.protocol import Done, Dones, Tick
from node_runtime.runtime.rejections import BAD_MAC, STALE_EPOCH, UNKNOWN_SENDER, WRONG_SHAPE, WRONG_TICK
from node_runtime.runtime.transport import Transport

HOLD_LIMIT = 256  # held publications that wake their process anyway: what waits for it stays small (each is
# a few hundred bytes) however long it sleeps


class ClockError(RuntimeError):
    pass


class ProcessFailed(ClockError):
    """A node process failed; ``trace`` is its own account (a traceback), when it could give one."""

    def __init__(self, proc: str, nodes: tuple[str, ...], why: str, trace: str = "") -> None:
        what = f"node {nodes[0]}" if len(nodes) == 1 else f"nodes {', '.join(nodes)}"
        super().__init__(f"process {proc} ({what}) {why}")
        self.proc = proc
        self.nodes = nodes
        self.trace = trace


class Clock:
    def __init__(self, transport: Transport, keys: Keys, plan: ProcessLayout, keyring: Keyring, timeout: float = 30.0,
                 health: Callable[[], None] | None = None, why_silent: Callable[[list[str]], str] | None = None,
                 placement: dict[str, list[str]] | None = None) -> None:
        """``keyring``: every key (the orchestrator), or those of one epoch (a driver's grant); ``health`` raises
        when a process is known to have failed; ``why_silent(procs)`` adds what is known of processes that sent
        no report in time (e.g. their OS state); ``placement`` (group -> processes): the hosts that may forward
        their processes' reports together."""
        self.transport = transport
        self.keys = keys
        self.plan = plan
        self.keyring = keyring
        self.epoch = keyring.epoch or 0  # of this clock's ticks
        self.procs = plan.procs
        self.timeout = timeout
        self.health = health
        self.why_silent = why_silent
        self.episode = -1
        self.latest = -1  # the highest episode run or seen on the bus (another driver may have run some)
        self.tick = -1
        self.expect: dict[int, int] = {}  # process index -> publications to wait for
        self.held = [0] * len(self.procs)  # process index -> publications held for it since it last ran
        self.held_due = [math.inf] * len(self.procs)  # process index -> the tick it must run by to read them
        self.wake: list[int | None] = [None] * len(self.procs)  # process index -> next tick with work of its own
        self.actors = {role: plan.proc_index[plan.proc_of[role]] for role in plan.roles}
        self.tick_keys = [keys.tick(p) for p in self.procs]  # process index -> its own tick key
        self.dones: dict[str, Done] = {}
        self.accepted: list[Done | None] = [None] * len(self.procs)  # process index -> its last report taken
        self.opened: frozenset[int] = frozenset()  # the processes the current tick was opened for
        self.early: frozenset[int] = frozenset()  # the processes the next tick was opened for ahead (open_next)
        # what each process may report on: its done key, its roles, the processes it sends to
        self.done_keys = {keys.done(p): i for i, p in enumerate(self.procs)}
        self.hosted = [frozenset(plan.role_index[r] for r in plan.roles_of[p]) for p in self.procs]
        self.receivers = [frozenset(plan.proc_index[q] for q in plan.recipients[p]) for p in self.procs]
        # workers whose states go through the clock -> the processes that listen to them (host.states_by_clock);
        # the latest state of each, and what each process has yet to read
        self.state_listeners = self._state_listeners(plan)
        self.state_roles = frozenset(plan.role_index[r] for r in plan.roles if plan.publications[r])
        self.last_states: dict[int, tuple[int, int, float, int, int]] = {}  # worker role index -> (queue,
        # occupancy, drains_at, sent, seq)
        self.unread: list[set[int]] = [set() for _ in self.procs]  # process index -> workers in ``last_states``
        self.rejections = transport.rejections
        self.node_rejections: dict[int, dict[str, int]] = {}  # process index -> what it refused, by reason
        # reports accepted: on their own, in hosts' messages; and how many such messages brought them
        self.reports = {"alone": 0, "from_hosts": 0, "host_messages": 0}
        self.host_keys = {keys.dones(group): frozenset(p for p in procs if p in plan.proc_index)
                          for group, procs in (placement or {}).items()}
        self.groups = {group: frozenset(procs) for group, procs in (placement or {}).items()}
        self.group_keys = {keys.dones(group): group for group in self.groups}
        self.heard: dict[str, float] = {}  # group -> when its host last sent a batch (its reports, or an empty one)
        transport.subscribe(keys.done(), self.on_done)
        if self.host_keys:
            transport.subscribe(keys.dones(), self.on_dones)

    @staticmethod
    def _state_listeners(plan: ProcessLayout) -> dict[int, tuple[int, ...]]:
        out = {}
        for proc in plan.procs:
            if not states_by_clock(proc, plan):
                continue
            for worker in plan.roles_of[proc]:
                listening = {plan.proc_of[r] for r in plan.subscribers.get(state_topic(role_node(worker)), ())}
                listening.discard(proc)
                if listening and plan.publications[worker]:
                    out[plan.role_index[worker]] = tuple(sorted(plan.proc_index[p] for p in listening))
        return out

    def on_done(self, key: str, done: Done) -> None:
        if type(done) is not Done:
            self.rejections.add(key, WRONG_SHAPE, f"a {type(done).__name__} where a done was expected")
            return
        i = self.done_keys.get(key)
        if i is None or self.procs[i] != done.proc:
            self.rejections.add(key, UNKNOWN_SENDER, f"a done of {done.proc!r}, which does not publish on this key")
            return
        if self.proven(key, self.keyring.proc_key(done.proc, done.epoch), done) and self.accept(key, i, done):
            self.reports["alone"] += 1

    def on_dones(self, key: str, dones: Dones) -> None:
        """A host's reports of a tick, each checked as if it had come alone."""
        if type(dones) is not Dones:
            self.rejections.add(key, WRONG_SHAPE, f"a {type(dones).__name__} where a host's dones were expected")
            return
        group = self.group_keys.get(key)
        if group is None or dones.group != group:
            self.rejections.add(key, UNKNOWN_SENDER, f"the dones of group {dones.group!r}, which does not publish here")
            return
        if not self.proven(key, self.keyring.host_key(group, dones.epoch), dones):
            return
        self.heard[group] = time.monotonic()  # only a batch with the host's MAC says it is there
        placed = self.host_keys[key]
        accepted = 0
        for done in dones.dones:
            if done.proc not in placed:
                self.rejections.add(key, UNKNOWN_SENDER, f"a done of {done.proc!r}, which this host does not run")
            elif done.epoch != dones.epoch:
                self.rejections.add(key, STALE_EPOCH, f"a done of epoch {done.epoch} among reports of {dones.epoch}")
            elif self.accept(key, self.plan.proc_index[done.proc], done):
                accepted += 1
        if accepted:
            self.reports["from_hosts"] += accepted
            self.reports["host_messages"] += 1

    def proven(self, key: str, secret: bytes | None, msg: Done | Dones) -> bool:
        """Whether a report carries the MAC of the sender it names (``secret``: its key of the report's epoch, None
        where this side cannot know it); if not, it is refused and counted."""
        if secret is None and msg.epoch != self.epoch:  # a driver holds the keys of its own epoch only
            self.rejections.add(key, STALE_EPOCH, f"a report of epoch {msg.epoch}; the clock is in epoch {self.epoch}")
            return False
        if not authentic(secret, msg):
            self.rejections.add(key, BAD_MAC, f"a report of tick {getattr(msg, 'tick', '?')} without its sender's MAC")
            return False
        return True

    def accept(self, key: str, i: int, done: Done) -> bool:
        """Take the report of process ``i`` that came on ``key`` (its MAC proven), unless it cannot be trusted;
        True if taken. Raises ``ProcessFailed`` for a failure it reports, or two different reports of one tick."""
        if done.epoch != self.epoch:
            if done.epoch > self.epoch and self.episode < done.episode <= self.latest + 1:
                self.latest = done.episode  # a driver's run (launch --serve)
            elif done.epoch < self.epoch:
                self.rejections.add(key, STALE_EPOCH, f"epoch {done.epoch}; the clock is in epoch {self.epoch}")
            else:
                self.rejections.add(key, WRONG_TICK, f"episode {done.episode} of epoch {done.epoch}; the clock is in "
                                                     f"episode {self.episode} of epoch {self.epoch}")
            return False
        prior = self.accepted[i]
        if prior is not None and prior.episode == done.episode and prior.tick == done.tick:
            if prior == done:
                self.rejections.add(key, WRONG_TICK, f"a copy of its report of tick {done.tick}")
                return False
            raise ProcessFailed(done.proc, self.plan.node_of_proc(done.proc),
                                f"sent two different reports of tick {done.tick}, both with its MAC: its key is in "
                                "other hands, and nothing tells which report is true")
        if done.episode != self.episode:
            if self.episode < done.episode <= self.latest + 1:  # another driver's episode (launch --serve)
                self.latest = done.episode
            else:
                self.rejections.add(key, WRONG_TICK, f"episode {done.episode}; the clock is in episode {self.episode}")
            return False
        why = self.untrusted(i, done)
        if why is not None:
            self.rejections.add(key, *why)
            return False
        if done.error is not None:
            first = done.error.strip().splitlines()[0]
            raise ProcessFailed(done.proc, self.plan.node_of_proc(done.proc), f"failed in tick {done.tick}: {first}",
                                done.error)
        if done.rejected:
            self.node_rejections[i] = done.rejected
        self.dones[done.proc] = done
        self.accepted[i] = done
        return True

    def untrusted(self, i: int, done: Done) -> tuple[str, str] | None:
        """Why a done of the current episode from process ``i`` cannot be its report (reason, detail), or None."""
        t, expected = (self.tick + 1, self.early) if self.early else (self.tick, self.opened)
        if done.tick != t or i not in expected:
            return WRONG_TICK, f"tick {done.tick}; the clock waits for tick {t} from other processes"
        if done.proc in self.dones:
            return WRONG_TICK, f"a second done for tick {t}"
        hosted = self.hosted[i]
        stats, flights, times, obs, sent = done.stats, done.flights, done.response_times, done.obs, done.sent
        ledger, drift, held, states, reports = done.ledger, done.drift, done.held, done.states, done.reports
        if not ((not stats or hosted.issuperset(stats)) and (not flights or hosted.issuperset(flights))
                and (not times or hosted.issuperset(times)) and (not obs or hosted.issuperset(obs))
                and (not ledger or hosted.issuperset(ledger)) and (not drift or stats.keys() >= drift.keys())
                and (not states or (hosted.issuperset(states) and self.state_roles.issuperset(states)))
                and (not reports or hosted.issuperset(reports))
                and (not sent or self.receivers[i].issuperset(sent))
                and (not held or self.receivers[i].issuperset(held))):
            return UNKNOWN_SENDER, (f"a report on roles {done.proc} does not host, on mail to processes it "
                                    "never sends to, or a drift without its stats")
        for arrivals in flights.values():
            if min(arrivals, default=t + 1) <= t:
                return WRONG_TICK, f"tasks on links that arrive at tick {min(arrivals)}, sent in tick {t}"
        for _, due in held.values():
            if due is not None and due <= t + 1:
                return WRONG_TICK, f"mail held until tick {due}, sent in tick {t}: it is read next tick"
        for arrive, _, _ in reports.values():
            if arrive <= t:
                return WRONG_TICK, f"a report that arrives at tick {arrive}, sent in tick {t}"
        return None

    def node_rejected(self) -> dict[str, int]:
        """What the node processes refused so far, by reason, as their latest reports say."""
        total: dict[str, int] = {}
        for counts in self.node_rejections.values():
            for reason, n in counts.items():
                total[reason] = total.get(reason, 0) + n
        return dict(sorted(total.items()))

    def reset(self, seed: int, external: list[str] | None = None, policy: str | None = None) -> list[Done]:
        """Start a new episode: every process resets its roles, then runs tick 0."""
        if self.early:  # a tick opened ahead is abandoned: its reports come first, then nothing is left behind
            self.tick += 1
            self.opened, self.early = self.early, frozenset()
            self._collect(sorted(self.opened))
        self.episode = max(self.episode, self.latest) + 1
        self.latest = self.episode
        self.tick = 0
        self.dones = {}
        self.accepted = [None] * len(self.procs)
        self.held = [0] * len(self.procs)  # what was held in the last episode was dropped with it
        self.held_due = [math.inf] * len(self.procs)
        self.last_states = {}
        self.unread = [set() for _ in self.procs]
        self.opened = frozenset(range(len(self.procs)))
        self._send(self.keys.tick(), Tick(self.episode, 0, "reset", seed=seed, external=list(external or ()),
                                          policy=policy))
        return self._collect(range(len(self.procs)))

    def step(self, actions: dict[str, Any] | None = None) -> list[Done]:
        """Run the next tick; ``actions`` go to externally driven controllers."""
        self.tick += 1
        t = self.tick
        mine: dict[int, dict[str, Any]] = {}  # process index -> actions for its controllers
        for role, action in (actions or {}).items():
            mine.setdefault(self.actors[role], {})[role] = action
        early, self.early = self.early, frozenset()
        if not early.isdisjoint(mine):
            raise ClockError(f"tick {t}: actions for controllers of processes whose tick opened ahead without them "
                             f"({', '.join(self.procs[i] for i in sorted(early & mine.keys()))})")
        opened = self._due(t, mine)
        if early:  # open_next already took what was held for them
            opened = sorted(early.union(opened))
        else:
            self.dones = {}
        self.opened = frozenset(opened)
        self._open(t, [i for i in opened if i not in early], mine, actions or {})
        return self._collect(opened)

    def open_next(self, hold: Collection[str] = ()) -> None:
        """Open the next tick now for the processes due in it, except those hosting a controller in ``hold``
        (the ones that may still get actions for it): they run it while the caller is busy with this one,
        and ``step`` opens the rest. Their tick is the one ``step`` would have sent them, so nothing changes
        but when it runs."""
        t = self.tick + 1
        held = {self.actors[role] for role in hold}
        early = [i for i in self._due(t, {}) if i not in held]
        self.dones = {}
        self.early = frozenset(early)
        self._open(t, early, {}, {})

    def _due(self, t: int, mine: Collection[int]) -> list[int]:
        """The processes tick ``t`` must be opened for: mail announced, actions, work due, or too much held."""
        expect, held, due = self.expect, self.held, self.held_due
        return [i for i, wake in enumerate(self.wake) if i in expect or i in mine or (wake is not None and wake <= t)
                or due[i] <= t or held[i] >= HOLD_LIMIT]

    def _open(self, t: int, procs: list[int], mine: dict[int, dict[str, Any]], actions: dict[str, Any]) -> None:
        """Publish tick ``t`` to ``procs``: each its own expected count (with what was held for it) and ``mine``,
        its share of ``actions``."""
        held = self.held
        counts = {}
        for i in procs:
            n = self.expect.get(i, 0) + held[i]
            held[i] = 0
            self.held_due[i] = math.inf
            if n:
                counts[i] = n
        latest, unread = self.last_states, self.unread
        if len(procs) == len(self.procs):  # one publication reaches them all, with every state one has yet to read
            states = {w: latest[w] for i in procs for w in unread[i]}
            for i in procs:
                unread[i].clear()
            self._send(self.keys.tick(), Tick(self.episode, t, "run", counts, actions, states=states))
            return
        for i in procs:
            states = {}
            if unread[i]:
                states = {w: latest[w] for w in unread[i]}
                unread[i].clear()
            self._send(self.tick_keys[i], Tick(self.episode, t, "run", {i: counts[i]} if i in counts else {},
                                               mine.get(i, {}), states=states))

    def _send(self, key: str, tick: Tick) -> None:
        """Publish a tick of this clock's epoch, sealed with its key of that epoch."""
        tick.epoch = self.epoch
        self.transport.publish(key, tick, self.keyring.clock_key(self.epoch))

    def catch_up(self, episode: int) -> None:
        """Another driver ran episodes up to ``episode``: number ours after them."""
        self.latest = max(self.latest, episode)

    def stop(self) -> None:
        self._send(self.keys.tick(), Tick(self.episode, self.tick + 1, "stop"))

    def fence(self) -> None:
        """Tell the processes the clock is held in its epoch now (``serve.py``, as a claim ends): they refuse the
        ticks of older ones."""
        self._send(self.keys.tick(), Tick(self.episode, self.tick, "fence"))

    def _silent_hosts(self, silent: list[str]) -> list[tuple[str, float | None]]:
        """The hosts to blame for silent processes: (group, seconds since anything came from its host). One that
        beats (an aggregator, ``DoneAggregator.beat``) is to blame once silent for half the timeout; one that does
        not, when none of its processes reported this tick (a stopped process alone is named, as its host
        forwards the others' reports)."""
        now, quiet = time.monotonic(), []
        for group, procs in self.groups.items():
            if procs.isdisjoint(silent):
                continue
            heard = self.heard.get(group)
            if heard is not None and now - heard > self.timeout / 2:
                quiet.append((group, now - heard))
            elif heard is None and procs.isdisjoint(self.dones):
                quiet.append((group, None))
        return quiet

    def _collect(self, opened: Sequence[int]) -> list[Done]:
        """Wait for the Done of every process the tick was opened for, in canonical order."""
        n = len(opened)
        try:
            self.transport.dispatch(until=lambda: len(self.dones) == n, timeout=self.timeout, idle=self.health)
        except TimeoutError:
            silent = [self.procs[i] for i in opened if self.procs[i] not in self.dones]
            nodes = sorted({nd for p in silent for nd in self.plan.node_of_proc(p)})
            last = self.rejections.last
            refused = [f"{p}: {last[k]}" for p in silent if (k := self.keys.done(p)) in last]
            state = self.why_silent(silent) if self.why_silent else ""
            hosts = self._silent_hosts(silent)
            blame = "".join(f"the host of group {group} hung or was cut off: nothing came from it"
                            + (f" for {quiet:.1f} s" if quiet is not None else " for any of its processes")
                            + "; " for group, quiet in hosts)
            raise ClockError(f"tick {self.tick}: {blame}{', '.join(silent[:8])}{' ...' if len(silent) > 8 else ''} "
                             f"(nodes {', '.join(nodes[:8])}) " + ("sent" if hosts else "hung:")
                             + f" no report within {self.timeout:g} s{state}"
                             + ("; its zenohedge-node stood still, or the network to it failed" if hosts else "")
                             + (f"; refused from them: {'; '.join(refused[:3])}" if refused else "")) from None
        dones = [self.dones[self.procs[i]] for i in opened]
        expect: dict[int, int] = {}
        held, held_due = self.held, self.held_due
        listeners, latest, unread = self.state_listeners, self.last_states, self.unread
        for i, d in zip(opened, dones, strict=True):
            self.wake[i] = d.wake
            for w, (queue, occupancy, drains_at, seq) in d.states.items():
                readers = listeners.get(w)
                if readers:  # its listeners read it when they next run (Tick.states)
                    latest[w] = (queue, occupancy, drains_at, d.tick, seq)
                    for p in readers:
                        unread[p].add(w)
            for p, count in d.sent.items():
                expect[p] = expect.get(p, 0) + count
            for p, (count, due) in d.held.items():
                held[p] += count
                if due is not None and due < held_due[p]:
                    held_due[p] = due
        self.expect = expect
        return dones
