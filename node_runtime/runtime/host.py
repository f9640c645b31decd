"""A host runs the roles placed in one process and sorts their mail.

It knows nothing of the transport: ``run`` executes one tick of every role and returns what must
leave the process (one batch of mail per destination process, one batch of the broadcasts other
processes hear) together with the ``Done`` report. Mail between co-located roles never leaves the
host, but obeys the same rules: delivered at its arrival tick, applied in canonical order (arrive,
sender role, seq).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

from node_runtime.model.controller import Action, Controller
from node_runtime.model.messages import Envelope, Kind, NodeState
from node_runtime.model.plugins import load
from node_runtime.model.role import COMPLETED, Outbox, Role, read_stats, role_id, role_node, state_topic
from node_runtime.model.view import Observation
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.protocol import Done

CARRIES_TASK = (Kind.TASK, Kind.RESULT)
NO_MAIL: tuple[Envelope, ...] = ()


@dataclass(slots=True)
class Outgoing:
    batches: dict[str, list[Envelope]]  # destination process -> envelopes
    broadcasts: list[Envelope]  # for every process in ``plan.listeners[proc]``
    done: Done
    events: list[tuple[str, str, dict]]  # (kind, node, fields), collected only while a monitor listens


def role_class(role: str, plan: ProcessLayout) -> type[Role]:
    """Its kind's class, or the scenario's subclass of it (``roles:`` key)."""
    kind = plan.kind_of(role)
    impl = plan.scenario.node[role_node(role)].impl(kind.name)
    return load(impl, kind.base) if impl else kind.base


def make_role(role: str, plan: ProcessLayout) -> Role:
    """The role, of ``role_class``."""
    return role_class(role, plan)(plan.scenario.node[role_node(role)], plan.scenario)


def holders(proc: str, plan: ProcessLayout) -> frozenset[str]:
    """The processes listening to ``proc``'s broadcasts whose every subscribing role holds them
    (``Role.holds_broadcasts``): they read them at their next run, rather than wake for them."""
    return frozenset(p for p in plan.listeners[proc] if all(
        role_class(r, plan).holds_broadcasts for r in plan.roles_of[p] if plan.subscriptions[r]))


def states_by_clock(proc: str, plan: ProcessLayout) -> bool:
    """Whether the states ``proc``'s workers broadcast reach the other processes through the clock rather than
    as mail: when every process that listens holds them. Only the latest state of a node matters to a role that
    holds broadcasts (it overwrites what it knew), so the clock keeps that and hands it over in the listener's
    next tick (``Tick.states``; docs/protocol.md, "States that go with the ticks"): no publication wakes or waits
    for it."""
    listeners = plan.listeners[proc]
    return bool(listeners) and holders(proc, plan) == frozenset(listeners)


class Host:
    def __init__(self, proc: str, plan: ProcessLayout) -> None:
        self.proc = proc
        self.plan = plan
        self.roles: list[Role] = [make_role(r, plan) for r in plan.roles_of[proc]]
        self.by_id = {r.id: r for r in self.roles}
        self.drivable = {r.id for r in self.roles if plan.kind_of(r.id).agent}  # roles an agent can drive
        self.outboxes = {r.id: Outbox(r.id) for r in self.roles}
        # For each topic: the subscribers here; and the topics of this host's roles that other processes hear
        self.local_subs = {topic: [r for r in subs if r in self.by_id] for topic, subs in plan.subscribers.items()}
        self.heard_elsewhere = {topic for r in self.roles for topic in plan.publications[r.id]
                                if any(plan.proc_of[s] != proc for s in plan.subscribers.get(topic, ()))}
        self.listeners = plan.listeners[proc]
        # the listeners that take this process's broadcasts at their next run instead of waking for them
        # (``Done.held``); when they all do, its workers' states reach them through the clock instead
        self.holders = holders(proc, plan)
        self.states_by_clock = states_by_clock(proc, plan)
        # the workers elsewhere whose states roles here hear, and those of them whose states come with the ticks
        by_clock = {p: states_by_clock(p, plan) for p in plan.broadcasters[proc]}
        heard = [w for p in by_clock for w in plan.roles_of[p]
                 if plan.publications[w] and self.local_subs.get(state_topic(role_node(w)))]
        self.states_heard = frozenset(plan.role_index[w] for w in heard)
        self.states_from_clock = frozenset(plan.role_index[w] for w in heard if by_clock[plan.proc_of[w]])
        # Co-located control (control_latency 0; the layout keeps a node's controller with its worker):
        # controllers answer before the other roles run and observe after them (``run``).
        self.colocated: list[tuple[Controller, str]] = []  # (controller, its worker's role id)
        if plan.scenario.colocated_control:
            for role in self.roles:
                if isinstance(role, Controller):
                    worker = self.by_id[role_id("worker", role.node.id)]
                    role.bind(worker)
                    self.colocated.append((role, worker.id))
        self.stepped = [r for r in self.roles if not any(r is c for c, _ in self.colocated)]
        self.external: set[str] = set()
        self.events_on = False  # set by the driver while a monitor subscribes to events
        self.episode = 0
        self.reset(0, plan.scenario.seed)

    @property
    def nodes(self) -> list[str]:
        return list(dict.fromkeys(r.node.id for r in self.roles))

    def reset(self, episode: int, seed: int, external: frozenset[str] = frozenset(),
              policy: str | None = None) -> None:
        """Start episode ``episode``: fresh roles' state and empty mailboxes."""
        self.episode = episode
        self.external = set(external) & set(self.by_id)
        # an agent drives the episode, here or elsewhere: its credit needs the ledger, and the observations the
        # environment re-times need the states broadcast and the reports held
        self.driven = bool(external)
        for role in self.roles:
            if role.id in self.drivable:
                role.reset(seed, external=role.id in self.external, policy=policy)
            else:
                role.reset(seed)
        self.mail: dict[str, defaultdict[int, list[Envelope]]] = {r.id: defaultdict(list) for r in self.roles}
        self.due: dict[str, float] = dict.fromkeys(self.by_id, 0)  # the next tick each role must run
        self.reported: dict[str, tuple] = {}  # what each role's stats were at the last report
        self.coasting: set[str] = set()  # roles whose last report gave a drift (Role.drift)
        self.states_taken: dict[int, tuple[int, int]] = {}  # worker role index -> (sent, seq) of the last state
        # the clock handed over (``take_states``)
        self.earliest = math.inf  # the earliest arrival tick of the mail delivered and not yet taken
        self.held: list[tuple[str, Envelope]] = []  # mail of roles here to roles here that read it later
        for out in self.outboxes.values():
            out.reset()

    def deliver(self, envelopes: list[Envelope]) -> None:
        """Mail that came over the bus, addressed to a role here or to a topic one subscribes to."""
        mail = self.mail
        for env in envelopes:
            if env.kind == Kind.STATE:
                for r in self.local_subs.get(env.dst, ()):
                    mail[r][env.arrive].append(env)
            else:
                mail[env.dst][env.arrive].append(env)
            if env.arrive < self.earliest:
                self.earliest = env.arrive

    def take_states(self, states: dict[int, tuple[int, int, float, int, int]]) -> None:
        """States broadcast to the roles here that the clock kept for them (``Tick.states``: worker role index ->
        queue, occupancy, drains_at, tick sent, seq): delivered as the broadcasts they stand for, at the tick after
        they were sent. Only the latest of each worker's comes, which is all a role that holds broadcasts reads."""
        roles, taken, mail = self.plan.roles, self.states_taken, self.mail
        for w, (queue, occupancy, drains_at, sent, seq) in states.items():
            # a tick for every process carries the states any of them has yet to read: those not heard here, and
            # those already taken, are skipped
            if w not in self.states_from_clock or taken.get(w, (-1, -1)) >= (sent, seq):
                continue
            taken[w] = (sent, seq)
            worker = roles[w]
            node = role_node(worker)
            topic = state_topic(node)
            state = NodeState(node, queue, occupancy, drains_at)
            env = Envelope(Kind.STATE, worker, topic, seq, sent, sent + 1, state)
            for r in self.local_subs[topic]:
                mail[r][sent + 1].append(env)
            self.earliest = min(self.earliest, sent + 1)

    def take_held(self, t: int) -> None:
        """Mail held for roles here arrived at ticks the process slept through: it joins tick t's mail, still
        in canonical order (``_tick`` sorts by arrival first), as if each envelope had been read when it arrived."""
        for box in self.mail.values():
            late = [a for a in box if a < t]
            if late:
                inbox = box[t]
                for a in sorted(late):
                    inbox.extend(box.pop(a))

    def run(self, t: int, actions: dict[str, Action] | None = None) -> Outgoing:
        """One tick of every role with mail or work due, in canonical order; mail out; the report.

        A role with neither is skipped: by the contract of ``Role.wake`` its tick would change nothing.
        Co-located controllers first answer their last observation, their decisions reaching their
        workers in this tick, and run after every other role.
        """
        actions = actions or {}
        mail = self.mail
        if self.held:
            for r, env in self.held:
                mail[r][env.arrive].append(env)
                self.earliest = min(self.earliest, env.arrive)
            self.held = []
        if self.earliest < t:
            self.take_held(t)
        self.earliest = math.inf
        due = self.due
        events: list[tuple[str, str, dict]] = []
        ran: list[Role] = []
        if self.colocated:
            self._answer(t, actions, events)
        for role in self.stepped:
            inbox = mail[role.id].pop(t, NO_MAIL)
            if inbox or due[role.id] <= t:
                self._tick(role, t, inbox, actions, events)
                ran.append(role)
        if self.colocated:
            self._observe(t, actions, ran, events)
        return self._route(t, ran, events)

    def _answer(self, t: int, actions: dict[str, Action], events: list[tuple[str, str, dict]]) -> None:
        """Co-located controllers place their answers; the decisions are the worker's mail of this tick."""
        for ctrl, worker in self.colocated:
            if not ctrl.asked:
                continue
            out = self.outboxes[ctrl.id]
            out.tick = t
            out.events = events if self.events_on else None
            if ctrl.down(t):
                ctrl.asked, ctrl.pending = [], None
                continue
            ctrl.answer(t, out, actions.get(ctrl.id))
            for env in out.envelopes:
                env.arrive = t
                self.mail[worker][t].append(env)
            out.envelopes.clear()

    def _observe(self, t: int, actions: dict[str, Action], ran: list[Role],
                 events: list[tuple[str, str, dict]]) -> None:
        """Co-located controllers run after their workers: with mail or work due, or when the worker ran."""
        workers = {r.id for r in ran}
        for ctrl, worker in self.colocated:
            inbox = self.mail[ctrl.id].pop(t, NO_MAIL)
            if inbox or self.due[ctrl.id] <= t or worker in workers:
                self._tick(ctrl, t, inbox, actions, events)
                ran.append(ctrl)

    def _tick(self, role: Role, t: int, inbox: list[Envelope], actions: dict[str, Action],
              events: list[tuple[str, str, dict]]) -> None:
        """One role's tick: its mail in canonical order, its outbox, its action if an agent drives it."""
        rid = role.id
        if len(inbox) > 1:
            inbox.sort(key=Envelope.order)
        out = self.outboxes[rid]
        out.tick = t
        out.events = events if self.events_on else None
        if rid in self.external:
            role.tick(t, inbox, out, actions.get(rid))
        else:
            role.tick(t, inbox, out)
        self.due[rid] = role.wake(t)

    def wake(self) -> int | None:
        """The next tick at which a role here has work or mail, or None if only new mail can wake one."""
        nxt = min(self.due.values(), default=math.inf)
        for box in self.mail.values():
            if box:
                nxt = min(nxt, min(box))
        return None if nxt == math.inf else int(nxt)

    def _route(self, t: int, ran: list[Role], events: list[tuple[str, str, dict]]) -> Outgoing:
        proc_of = self.plan.proc_of
        role_index = self.plan.role_index
        batches: dict[str, list[Envelope]] = {}
        broadcasts: list[Envelope] = []
        sent: dict[int, int] = {}
        held: dict[int, tuple[int, int | None]] = {}
        states: dict[int, tuple[int, int, float, int]] = {}
        reports: dict[int, tuple[int, int, list[float] | None]] = {}
        flights: dict[int, dict[int, int]] = {}
        for role in ran:
            out = self.outboxes[role.id]
            if not out.envelopes and not out.broadcasts:
                continue
            for env in out.envelopes:
                if env.kind in CARRIES_TASK:
                    landing = flights.setdefault(role_index[role.id], {})
                    landing[env.arrive] = landing.get(env.arrive, 0) + 1
                dst = env.dst
                if dst not in self.mail:
                    batches.setdefault(proc_of[dst], []).append(env)
                elif self.by_id[dst].reads_later(env):  # it waits for the role's next run (Role.reads_later)
                    self.held.append((dst, env))
                    if self.driven and env.kind == Kind.REPORT:
                        reports[role_index[dst]] = (env.arrive, len(env.body.pending), env.body.busy_until)
                else:
                    self.mail[dst][env.arrive].append(env)
            for env in out.broadcasts:
                for r in self.local_subs.get(env.dst, ()):
                    if self.by_id[r].reads_later(env):  # as the listeners elsewhere hold it
                        self.held.append((r, env))
                    else:
                        self.mail[r][env.arrive].append(env)
                state = env.kind == Kind.STATE
                by_clock = state and self.states_by_clock  # the listeners elsewhere get it with their ticks
                elsewhere = env.dst in self.heard_elsewhere
                if elsewhere and not by_clock:
                    broadcasts.append(env)
                if state and ((by_clock and elsewhere) or self.driven):  # for the clock; for re-timed observations
                    body = env.body
                    states[role_index[role.id]] = (body.queue, body.occupancy, body.drains_at, env.seq)
            out.envelopes.clear()
            out.broadcasts.clear()
        index = self.plan.proc_index
        for p, envelopes in batches.items():
            first = min(env.arrive for env in envelopes)
            if first > t + 1:  # nothing in it is read before then: its process need not wake for it sooner
                held[index[p]] = (1, first)
            else:
                sent[index[p]] = 1
        if broadcasts:  # one batch reaches every listener, whichever topics it carries
            for p in self.listeners:
                i = index[p]
                if p in self.holders:
                    count, due = held.get(i, (0, None))
                    held[i] = (count + 1, due)
                else:
                    sent[i] = sent.get(i, 0) + 1
        return Outgoing(batches, broadcasts, self.report(t, ran, sent, flights, held, states, reports), events)

    def report(self, t: int, ran: list[Role], sent: dict[int, int], flights: dict[int, dict[int, int]],
               held: dict[int, tuple[int, int | None]], states: dict[int, tuple[int, int, float, int]],
               reports: dict[int, tuple[int, int, list[float] | None]]) -> Done:
        """The Done of tick t. Its stats hold only the roles whose counters changed since the last
        report (all of them after a reset): the orchestrator keeps the others' last values, moved on
        by their drift while they coast. Roles that did not run this tick cannot have changed but by it."""
        stats: dict[int, tuple] = {}
        rts: dict[int, list[float]] = {}
        ledger: dict[int, list[tuple[int, int, float]]] = {}
        obs: dict[int, Observation] = {}
        drift: dict[int, tuple] = {}
        reported = self.reported
        coasting = self.coasting
        index = self.plan.role_index
        for role in ran:
            rid = role.id
            st = role.stats
            values = read_stats(st)
            if role.drift is not None:
                drift[index[rid]] = role.drift
            if reported.get(rid) != values or rid in coasting or role.drift is not None:
                reported[rid] = stats[index[rid]] = values  # a drift starts or ends from exact values
                if role.drift is None:
                    coasting.discard(rid)
                else:
                    coasting.add(rid)
            if st.ledger:
                times = [value for _, kind, value in st.ledger if kind == COMPLETED]
                if times:
                    rts[index[rid]] = times
                if self.driven:
                    ledger[index[rid]] = st.ledger
                st.ledger = []
            if rid in self.external and role.last is not None and role.last.tick == t:
                obs[index[rid]] = role.last
        return Done(self.proc, self.episode, t, sent, stats, rts, flights, self.wake(), obs, ledger=ledger,
                    drift=drift, held=held, states=states, reports=reports)
