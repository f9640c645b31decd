"""The controller role: decides where its worker's undecided tasks go.

Timing, identical whether a node-side policy or an RL agent decides (so that a policy run in the
node and the same policy run as an agent through the environment give the same emulation):

- at the end of every decision epoch (ticks t with t % decision_interval == 0) the controller
  builds an ``Observation`` from what it has heard: its worker's undecided list (reported one tick
  late) and the one-hop state broadcasts (one tick late);
- the action for that observation is applied in the next tick: the controller turns it into
  ``Decision`` messages, which reach the worker one tick later.

With ``control_latency: 0`` the controller is co-located with its worker (``bind``): it reads the
worker's tasks, load and links at the end of every tick, and the host hands its decisions to the
worker at the start of the next, before the worker runs (docs/model.md).

Binary mode places the oldest undecided task per epoch; batch mode places up to ``batch_size``
undecided tasks, oldest first.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from itertools import chain
from types import MappingProxyType
from typing import TYPE_CHECKING, ClassVar

from node_runtime.model.messages import Decision, Envelope, Kind, NodeState, Pending
from node_runtime.model.policies import Policy, make_policy
from node_runtime.model.registry import RoleKind, register
from node_runtime.model.rng import stream
from node_runtime.model.role import Outbox, Role, role_id, state_topic
from node_runtime.model.spec import NodeSpec, Scenario
from node_runtime.model.view import NodeView, Observation, TaskView, backlog

if TYPE_CHECKING:
    from node_runtime.model.worker import Worker

Action = int | Sequence[int]


class InvalidAction(ValueError):
    """An action outside the valid targets of the observation it answers."""


class Controller(Role):
    kind = "controller"
    # ``observation_at`` re-times what this class observes. A subclass that observes otherwise (``observe``,
    # ``view``, ``own_view`` or ``tick`` redefined) runs every tick while an agent drives it, as all did before.
    retimed: ClassVar[bool] = True
    # A state heard while it is not due only overwrites what it knew of that node (ages come from the
    # scenario, not from when a state was read), so the state can wait for its next run; a subclass with
    # a ``tick`` of its own wakes for every state, as all did before.
    holds_broadcasts: ClassVar[bool] = True

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        cls.retimed = cls.retimed and not any(name in cls.__dict__ for name in ("observe", "view", "own_view", "tick"))
        cls.holds_broadcasts = cls.holds_broadcasts and "tick" not in cls.__dict__

    def __init__(self, node: NodeSpec, scenario: Scenario) -> None:
        super().__init__(node, scenario)
        self.neighbours = scenario.neighbours[node.id]
        self.worker = role_id("worker", node.id)
        self.per_epoch = 1 if scenario.mode == "binary" else scenario.batch_size
        self.external = False
        self.policy_spec = node.policy
        self.policy: Policy = make_policy(node.policy)
        self.own_worker: Worker | None = None  # set by ``bind`` (co-located control)
        self.reset(scenario.seed)

    def bind(self, worker: Worker) -> None:
        """Co-locate with the node's worker (control_latency 0): read it directly instead of its reports."""
        self.own_worker = worker
        self._seen_version = -1

    def reset(self, seed: int, external: bool = False, policy: str | None = None) -> None:
        """Start an episode. ``external``: an agent sends the actions; else the node-side policy —
        ``policy`` for this episode if given, the node's own otherwise."""
        super().reset(seed)
        self.external = external
        wanted = policy or self.node.policy
        if wanted != self.policy_spec:
            self.policy_spec, self.policy = wanted, make_policy(wanted)
        self.policy.reset(stream(seed, self.index, CONTROLLER.stream))
        sc = self.scenario
        self.states: dict[str, NodeState] = {
            n: NodeState(n, 0, 0, 0.0) for n in (self.node.id, *self.neighbours)
        }
        self.undecided: list[Pending] = []
        self.busy_until = [0.0] * len(self.neighbours)  # of the node's links, as last reported
        self._seen_version = -1  # co-located: the worker's version of its tasks last read
        self.decided: set[int] = set()
        self.asked: list[int] = []  # task ids of the last observation, which the next action places
        self.pending: list[int] | None = None  # the node-side policy's answer to it
        self.last: Observation | None = None
        self.stale = False  # driven: ran since its last observation, so the next epoch must observe again
        me = self.node.id
        # static facts of every node in view: (buffer, capacity, tier, rate from here, can take tasks)
        self._static = {n: (sc.node[n].buffer, sc.node[n].capacity, sc.node[n].tier,
                            0.0 if n == me else sc.link[(me, n)].rate_bps, sc.node[n].has("worker"))
                        for n in self.states}
        self._always_fresh = always_fresh(sc, self.states)
        # neighbours over a link that follows positions: heard only in range, seen at the rate of the moment
        self._moving = frozenset(n for n in self.neighbours if sc.moving_link(me, n))
        self._heard: dict[str, tuple[int, int]] = {}  # moving neighbour -> (last instant searched, heard_at then)

    # ----- the tick -----

    def tick(self, t: int, inbox: list[Envelope], out: Outbox, action: Action | None = None) -> None:
        worker = self.own_worker
        if worker is not None and worker.tasks_version != self._seen_version:
            self._seen_version = worker.tasks_version
            self.heard(worker.pending())
        if not inbox and not self.asked and not self.external and not self.undecided:
            return  # nothing heard, nothing to place, nothing to observe
        for env in inbox:
            if env.kind == Kind.STATE:
                if self.hears(env.body.node, env.sent):
                    self.states[env.body.node] = env.body
            elif env.kind == Kind.REPORT:
                self.heard(env.body.pending)
                if env.body.busy_until is not None:
                    self.busy_until = env.body.busy_until
            else:
                raise ValueError(f"{self.id}: unexpected {env.kind.name} from {env.src}")
        if self.down(t):
            self.asked, self.pending = [], None
            return

        if self.asked:
            self.answer(t, out, action)

        if t % self.scenario.decision_interval == 0 and (self.external or self.has_candidates()):
            obs = self.observe(t)
            self.last = obs
            self.asked = [task.id for task in obs.tasks]
            if not self.external and self.asked:
                self.pending = self.policy.decide(obs)
            self.stale = False
        else:
            self.stale = self.external

    def hears(self, node: str, tick: int) -> bool:
        """Whether a state ``node`` broadcast in ``tick`` reaches this controller: always, unless their link
        follows positions and they were out of range then."""
        return node not in self._moving or self.positions.in_range(self.node.id, node, tick)

    def heard_at(self, node: str, t: int) -> int:
        """``heard_at`` of ``node``, for a moving neighbour searched back only to where the last search of this
        episode began (observations come at growing ticks, and what was heard by then stays heard)."""
        if node not in self._moving:
            return heard_at(self.scenario, node, t)
        interval = self.scenario.state_interval
        top = t - 1 - (t - 1) % interval
        searched, found = self._heard.get(node, (-interval, -interval))
        if top < searched:  # an earlier tick than the last asked: search it all
            return heard_at(self.scenario, node, t, self.hears)
        s = top
        while s > searched and (self.scenario.is_failed(node, s) or not self.hears(node, s)):
            s -= interval
        if s > searched:
            found = s
        self._heard[node] = (top, found)
        return found

    def reads_later(self, env: Envelope) -> bool:
        """A state, and a report whose tasks it has all placed already: that brings nothing to place, it only
        updates what the controller would observe (how many tasks wait, its links' backlogs)."""
        return super().reads_later(env) or (self.holds_broadcasts and env.kind == Kind.REPORT
                                             and all(p.id in self.decided for p in env.body.pending))

    def heard(self, pending: list[Pending]) -> None:
        """The worker's tasks to place, as reported (or read, co-located)."""
        self.undecided = pending
        present = {p.id for p in pending}
        self.decided &= present

    def answer(self, t: int, out: Outbox, action: Action | None = None) -> None:
        """Place the answer to the last observation: the node-side policy's, or the agent's ``action``.
        A co-located controller's host calls this before its worker runs (unless the node is down)."""
        chosen = self.pending if not self.external else action
        if chosen is not None:
            self.place(chosen, out)
        self.asked, self.pending = [], None

    def wake(self, t: int) -> float:
        """Next tick while an answer is to be placed; at the next decision epoch while undecided tasks
        wait, or when an agent drives it and it ran since it last observed; otherwise only mail (a report,
        a state) wakes it. A driven controller that sleeps through an epoch would observe exactly its last
        observation re-timed (``observation_at``): the environment does that instead of waking it, except where
        nodes move (links change with every tick: it observes every epoch)."""
        if self.asked or self.outages or (self.external and (not self.retimed or self.scenario.radio is not None)):
            return t + 1
        if self.has_candidates() or self.stale:
            interval = self.scenario.decision_interval
            return t + interval - t % interval
        return math.inf

    def has_candidates(self) -> bool:
        decided = self.decided
        return any(p.id not in decided for p in self.undecided)

    def place(self, action: Action, out: Outbox) -> None:
        actions = [action] if isinstance(action, int) else list(action)
        if len(actions) < len(self.asked):
            raise InvalidAction(f"{self.id}: {len(actions)} action(s) for {len(self.asked)} task(s)")
        valid = self.last.valid_actions()
        decisions = []
        for task_id, a in zip(self.asked, actions, strict=False):
            a = int(a)
            if not 0 <= a < len(valid) or not valid[a]:
                raise InvalidAction(f"{self.id}: action {a} is not a valid target "
                                    f"(0 = local, 1..{len(self.neighbours)} = {', '.join(self.neighbours)})")
            decisions.append(Decision(task_id, "" if a == 0 else self.neighbours[a - 1]))
            self.decided.add(task_id)
        self.stats.decisions += len(decisions)
        out.send(Kind.DECISION, self.worker, decisions)

    # ----- the view -----

    def view(self, node: str, t: int, backlog: float = 0.0) -> NodeView:
        """What it knows of ``node``; ``backlog``: seconds queued on the link to it."""
        buffer, capacity, tier, rate, worker = self._static[node]
        state = self.states[node]
        if node in self._moving:
            rate = self.positions.rate(self.node.id, node, t)
        age = 1 if self._always_fresh else t - self.heard_at(node, t)
        return NodeView(node, state.queue, state.occupancy, buffer, capacity, tier, rate, age, worker, backlog,
                        state.drains_at)

    def own_view(self, t: int) -> NodeView:
        """Co-located: its own worker as it is at the end of tick t."""
        own = self.own_worker
        buffer, capacity, tier, rate, worker = self._static[self.node.id]
        return NodeView(self.node.id, own.stats.queue, own.occupancy, buffer, capacity, tier, rate, 0, worker, 0.0,
                        own.drains_at(t))

    def observe(self, t: int) -> Observation:
        dt = self.scenario.dt
        own_worker = self.own_worker
        busy_until = self.busy_until if own_worker is None else own_worker.radio.busy_until()
        tasks = []
        for p in self.undecided:
            if p.id in self.decided:
                continue
            age = (t - p.created) * dt
            tasks.append(TaskView(p.id, p.size, p.size.deadline - age, t - p.arrived, p.origin, p.job))
            if len(tasks) == self.per_epoch:
                break
        return Observation(
            tick=t,
            node=self.node.id,
            own=self.view(self.node.id, t) if own_worker is None else self.own_view(t),
            undecided=len(self.undecided),
            tasks=tasks,
            neighbours=[self.view(j, t, backlog(busy, t, dt))
                        for j, busy in zip(self.neighbours, busy_until, strict=False)],
            busy_until=list(busy_until),
        )


def heard_at(scenario: Scenario, node: str, t: int, hears: Callable[[str, int], bool] | None = None) -> int:
    """The tick whose end-state of ``node`` a controller knows at the end of tick ``t``.

    Broadcasts leave at ticks that are multiples of the state interval while the node is up,
    and arrive one tick later; unchanged states are not re-sent but still count as heard.
    ``hears(node, s)``: whether a broadcast of ``s`` reaches the controller (a moving node's, in range).
    """
    interval = scenario.state_interval
    s = t - 1
    s -= s % interval
    while s >= 0 and (scenario.is_failed(node, s) or (hears is not None and not hears(node, s))):
        s -= interval
    return s


def always_fresh(scenario: Scenario, nodes: Iterable[str]) -> bool:
    """With no failures in view, no moving node and a broadcast every tick, every state heard is exactly one
    tick old."""
    windows = scenario.failure_windows  # ``nodes`` is read only when some node has failures
    return scenario.state_interval == 1 and scenario.radio is None and (not windows or windows.keys().isdisjoint(nodes))


def observation_at(obs: Observation, t: int, scenario: Scenario,
                   states: Mapping[str, tuple[int, int, float]] = MappingProxyType({}),
                   report: tuple[int, list[float] | None] | None = None) -> Observation:
    """What the driven controller that made ``obs`` observes at tick ``t`` if it has neither run since
    nor anything to place: the same, re-timed (its states' ages, its links' backlogs), with what it heard
    meanwhile and holds unread (``reads_later``): ``states``, node -> the (queue, occupancy, drains_at) it last
    broadcast before tick ``t``; ``report``, the tasks pending and the links' busy-until ticks (None:
    unchanged) its worker's reports since told it. The environment calls this for a controller that
    slept through the epoch, rather than wake its process for it."""
    if obs.tasks:
        raise ValueError(f"controller:{obs.node}: an observation with tasks to place is never re-timed")
    fresh = always_fresh(scenario, chain((obs.node,), (n.node for n in obs.neighbours)))
    dt = scenario.dt

    def at(view: NodeView, queued: float) -> NodeView:  # the same view when nothing changed: most of them
        age = 1 if fresh else t - heard_at(scenario, view.node, t)
        state = states.get(view.node, (view.queue, view.occupancy, view.drains_at))
        if age == view.age and queued == view.backlog_s and state == (view.queue, view.occupancy, view.drains_at):
            return view
        return NodeView(view.node, *state[:2], view.buffer, view.capacity, view.tier, view.rate_bps, age, view.worker,
                        queued, state[2])

    undecided, busy_until = obs.undecided, obs.busy_until
    if report is not None:
        undecided = report[0]
        if report[1] is not None:
            busy_until = list(report[1])
    own = obs.own if scenario.colocated_control else at(obs.own, obs.own.backlog_s)
    return Observation(t, obs.node, own, undecided, [],
                       [at(n, backlog(busy, t, dt)) for n, busy in zip(obs.neighbours, busy_until, strict=False)],
                       busy_until)


def heard_states(node: NodeSpec, scenario: Scenario) -> tuple[str, ...]:
    """Its own node's state and its neighbours'."""
    return tuple(state_topic(n) for n in (node.id, *scenario.neighbours[node.id]))


CONTROLLER = register(RoleKind(Controller, order=2, stream=2, letter="k", needs=("worker",),
                               subscribes=heard_states, agent=True))
