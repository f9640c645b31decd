"""Rewards: the paper's Eq. 1–5, the reference implementation's variant, a sparse alternative, user
callables, potential-based shaping.

The paper's reward for agent i placing task k on target a (i itself when kept local) is

    R = r_u - (D + chi_O * O),   D = chi_wait * T_wait + chi_comm * T_comm + chi_exc * T_exc

It leaves choices open; docs/reward.md states and justifies each one, all in seconds:

- T_wait = Q_a * cycles_k / (N_a * phi_a): the target's queue (tasks admitted for processing, as last
  heard) times this task's cycles, over the target's capacity — queue in tasks, converted to time
  with the task at hand as the size estimate. Only the chosen target's queue counts.
- T_comm = 8 (alpha_in + alpha_out) / r_{i,a}: the input travels to the target and the result
  comes back; 0 when local.
- T_exc = cycles_k / (N_a phi_a) - cycles_k / (N_i phi_i) (negative when the target is faster).
- O = -ln(p) / 3 with p = max(epsilon, (Qmax_a - Q'_a) / Qmax_a) and
  Q'_a = min(max(0, Q_a - phi_a) + 1, Qmax_a), where Q_a is the target's buffer occupancy (minus
  this task itself when local, since it already sits in that buffer), phi_a the tasks it can finish
  in one tick (capacity * dt / cycles_k), ln the natural log and epsilon = 1e-3.

``reference`` is what PeersimGym's own code computed (docs/reward.md, "The reference implementation"):
the chi weights cap the times instead of scaling them, and the overload term uses log10 and the
expected arrivals.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from numbers import Real
from typing import Any

from node_runtime.model.plugins import is_import_path, load
from node_runtime.model.view import Observation, TaskView


@dataclass(frozen=True)
class PaperWeights:
    """The paper's Table "Parameter values"."""

    utility: float = 2.0  # r_u
    wait: float = 20.0  # chi_wait
    comm: float = 20.0  # chi_comm
    exc: float = 20.0  # chi_exc
    overload: float = 150.0  # chi_O
    epsilon: float = 1e-3  # floor of p, so that log(p) stays finite


@dataclass(frozen=True)
class RewardTerms:
    """Every term of one decision's paper reward (times in seconds)."""

    utility: float
    t_wait: float
    t_comm: float
    t_exc: float
    delay: float  # D
    overload: float  # O
    reward: float

    def as_dict(self) -> dict[str, float]:
        return {"utility": self.utility, "t_wait": self.t_wait, "t_comm": self.t_comm, "t_exc": self.t_exc,
                "delay": self.delay, "overload": self.overload, "reward": self.reward}


def paper_terms(obs: Observation, task: TaskView, action: int, dt: float,
                w: PaperWeights = PaperWeights()) -> RewardTerms:
    own = obs.own
    target = own if action == 0 else obs.neighbours[action - 1]
    cycles = task.size.cycles
    t_wait = target.queue * cycles / target.capacity
    t_comm = 0.0 if action == 0 else 8.0 * (task.size.input_bytes + task.size.output_bytes) / target.rate_bps
    t_exc = cycles / target.capacity - cycles / own.capacity
    delay = w.wait * t_wait + w.comm * t_comm + w.exc * t_exc
    occupancy = target.occupancy - (1 if action == 0 else 0)
    finish_per_tick = target.capacity * dt / cycles
    q_next = min(max(0.0, occupancy - finish_per_tick) + 1.0, float(target.buffer))
    p = max(w.epsilon, (target.buffer - q_next) / target.buffer)
    overload = -math.log(p) / 3.0
    return RewardTerms(w.utility, t_wait, t_comm, t_exc, delay, overload,
                       w.utility - (delay + w.overload * overload))


def reference_terms(obs: Observation, task: TaskView, action: int, dt: float, arrivals: Mapping[str, float],
                    w: PaperWeights = PaperWeights()) -> RewardTerms:
    """PeersimGym's reward as its code ran it; docs/reward.md tabulates how it differs from the paper.
    ``arrivals``: each node's nominal task arrival rate (tasks/s, ``nominal_arrivals``)."""
    own = obs.own
    local = action == 0
    target = own if local else obs.neighbours[action - 1]
    if not local and own.occupancy <= 1:  # offloading from a near-empty buffer: no cost is modelled
        return RewardTerms(w.utility, 0.0, 0.0, 0.0, 0.0, 0.0, w.utility)
    cap = w.utility
    # queue length in tasks over a capacity in cycles/s: the reference's units, hence near 0
    t_wait = own.occupancy / own.capacity + (0.0 if local else target.occupancy / target.capacity)
    t_wait = min(t_wait, cap * w.wait)
    t_comm = 0.0 if local else min(8.0 * task.size.input_bytes / target.rate_bps, cap * w.comm)
    t_exc = task.size.cycles / target.capacity - task.size.cycles / own.capacity
    t_exc = max(min(t_exc, cap * w.exc), -cap * w.exc)
    delay = t_wait + t_comm + t_exc
    expected = (target.occupancy + (0 if local else 1) + arrivals.get(target.node, 0.0) * dt
                - target.capacity * dt / task.size.cycles)
    q_next = max(min(expected, float(target.buffer)), 0.0)
    p = max(w.epsilon, (target.buffer - q_next) / target.buffer)
    overload = -math.log10(p) / 3.0 * cap * w.overload
    return RewardTerms(w.utility, t_wait, t_comm, t_exc, delay, overload, w.utility - (delay + overload))



CONGESTION_PRICE = 2.0  # what marginal_reward charges for a deadline's worth of delay imposed, in completions
# (RewardSettings' default, so ZenohEdgeEnv's and the experiments' --price; docs/reward.md says why 2)


@dataclass(frozen=True, kw_only=True)
class RewardSettings:
    """The numbers an environment's rewards and credits are computed with, checked once, here.

    ``weights``: the paper's r_u and chi weights (``ZenohEdgeEnv(reward_weights=...)``). ``congestion_price``:
    the price c that the ``marginal`` reward and the credits per task (env.credit) charge for a deadline's
    worth of waiting imposed on another task (``ZenohEdgeEnv(congestion_price=...)``, ``--price``)."""

    weights: PaperWeights = PaperWeights()
    congestion_price: float = CONGESTION_PRICE

    def __post_init__(self) -> None:
        if not isinstance(self.weights, PaperWeights):
            raise TypeError(f"reward_weights must be a PaperWeights, not a {type(self.weights).__name__}")
        c = self.congestion_price
        if isinstance(c, bool) or not isinstance(c, Real) or not 0 <= c < math.inf:
            raise ValueError(f"congestion_price must be a finite number >= 0, not {c!r}")
        object.__setattr__(self, "congestion_price", float(c))


@dataclass(slots=True, kw_only=True)
class RewardContext:
    """Everything a reward function may look at for one agent and one step (docs/reward.md, "Your own reward")."""

    agent: str
    node: str
    obs: Observation | None  # the view the agent acted on (None if its node was down)
    action: Any  # int, or a list of ints in batch mode; a choice the mask forbade reads 0 (kept local)
    next_obs: Observation | None
    terms: tuple[RewardTerms, ...]  # paper terms of each task placed by this action
    node_delta: Mapping[str, float]  # change of the node's counters during the step (completed, dropped, ...)
    network_delta: Mapping[str, float]  # the same changes as node_delta, network-wide
    dt: float
    arrivals: Mapping[str, float]  # each node's nominal task arrival rate, tasks/s (``nominal_arrivals``)
    penalty: float  # seconds the headline score charges a task that does not complete (its P)
    settings: RewardSettings = RewardSettings()  # the environment's weights and congestion price

    @property
    def weights(self) -> PaperWeights:
        """The environment's r_u and chi weights (``settings.weights``)."""
        return self.settings.weights

    @property
    def price(self) -> float:
        """``marginal``'s congestion price c (``settings.congestion_price``)."""
        return self.settings.congestion_price


RewardFn = Callable[[RewardContext], float]


def paper_reward(ctx: RewardContext) -> float:
    """Sum of the paper reward over the tasks placed (0 when there was nothing to decide)."""
    return sum(t.reward for t in ctx.terms)


def reference_reward(ctx: RewardContext) -> float:
    """Sum of the reference implementation's reward over the tasks placed (0 when nothing was decided)."""
    if ctx.obs is None or not ctx.obs.tasks:
        return 0.0
    actions = ctx.action if isinstance(ctx.action, list) else [ctx.action]
    return sum(reference_terms(ctx.obs, t, a, ctx.dt, ctx.arrivals, ctx.weights).reward
               for t, a in zip(ctx.obs.tasks, actions, strict=False))


def sparse_reward(ctx: RewardContext) -> float:
    """Tasks completed minus tasks dropped at the agent's node during the step."""
    return ctx.node_delta["completed"] - ctx.node_delta["dropped"]


def team_reward(ctx: RewardContext) -> float:
    """Tasks completed minus tasks dropped in the whole network during the step: the same for every agent.

    A cooperative reward: keeping a task local, which frees a shared server for the others' tasks, pays
    every agent, where a per-agent reward credits it to nobody (docs/reward.md)."""
    return ctx.network_delta["completed"] - ctx.network_delta["dropped"]


def timeliness(delta: Mapping[str, float], penalty: float) -> float:
    """Each completion in ``delta`` earns 1 - response / P: 1 when instant, 0 at the penalty. Summed over an
    episode and the network this is generated - (penalised response time x generated) / P, so maximising it
    minimises the headline score (the arrivals do not depend on the policy)."""
    return delta["completed"] - delta["response_time_total"] / penalty


def score_reward(ctx: RewardContext) -> float:
    """The headline score, credited to the origin: each of the node's own tasks that completed during the
    step earns 1 - response / P; a task that is dropped or never completes earns nothing."""
    return timeliness(ctx.node_delta, ctx.penalty)


def marginal_reward(ctx: RewardContext) -> float:
    """``score`` minus the congestion the agent's decisions caused: the waiting they imposed on other tasks
    (in CPU queues, and on the links they offloaded over), each wait in deadlines of the task that waited,
    times the price c (``ctx.price``: the environment's ``RewardSettings.congestion_price``).

    A difference reward (Wolpert and Tumer 2002; marginal-cost pricing in congestion games): a decision is
    charged what it takes from the others, so that agents each maximising their own reward maximise the
    team's score, without ``team_score``'s credit assignment over every agent. Counting a wait in the
    waiting task's deadlines prices it by what it risks: a task delayed by its whole deadline is lost, and
    2 s cost an alert due in 10 s ten times what they cost batch work due in 100 s (docs/reward.md)."""
    return timeliness(ctx.node_delta, ctx.penalty) - ctx.price * ctx.node_delta["delay_imposed"]


def team_score_reward(ctx: RewardContext) -> float:
    """``score`` over the whole network, the same for every agent (as ``team`` is to ``sparse``)."""
    return timeliness(ctx.network_delta, ctx.penalty)


REWARDS: dict[str, RewardFn] = {"paper": paper_reward, "reference": reference_reward, "sparse": sparse_reward,
                                "team": team_reward, "score": score_reward, "team_score": team_score_reward,
                                "marginal": marginal_reward}


TermsFn = Callable[[Observation, TaskView, int, float, PaperWeights, Mapping[str, float]], RewardTerms]


def terms_for(reward: RewardFn) -> TermsFn:
    """The terms ``infos[agent]["reward_terms"]`` shows: the reference implementation's under its reward,
    the paper's under any other (the paper's own, sparse, a user's)."""
    if reward is reference_reward:
        return lambda obs, task, action, dt, w, arrivals: reference_terms(obs, task, action, dt, arrivals, w)
    return lambda obs, task, action, dt, w, arrivals: paper_terms(obs, task, action, dt, w)


def resolve_reward(reward: str | RewardFn) -> RewardFn:
    """A built-in reward by name, a callable, or a callable's import path ("module:function")."""
    if callable(reward):
        return reward
    if is_import_path(reward):
        return load(reward, callable_ok=True)
    try:
        return REWARDS[reward]
    except KeyError:
        raise ValueError(f"unknown reward {reward!r}; expected one of {', '.join(REWARDS)}, a callable, "
                         "or an import path 'module:function'") from None


def shaped(reward: float, potential_before: float, potential_after: float, gamma: float) -> float:
    """Potential-based shaping (Ng et al. 1999): R' = R + gamma * Xi(s') - Xi(s); it keeps optimal policies."""
    return reward + gamma * potential_after - potential_before
