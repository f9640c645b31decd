"""What every agent shares: the ``AgentPolicy`` protocol, observation flattening, masked distributions, networks.

Nothing here knows the emulator: it works from the PettingZoo API and the observation conventions of
this project's environments (a dict with ``own`` (6,), ``task`` (7,) or (B, 7), ``neighbours`` (D, 8)
and ``action_mask``; ``task[TaskField.PRESENT] == 0`` means there is nothing to decide). The columns
are named by the environment's ``OwnField``, ``TaskField`` and ``NeighbourField``.
"""

from __future__ import annotations

import itertools
import random
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
import torch
from gymnasium import spaces
from torch import nn

from env.observations import NeighbourField, OwnField, TaskField

Observation = Mapping[str, Any]  # one agent's observation dict
Action = int | list[int]


@runtime_checkable
class AgentPolicy(Protocol):
    """Anything that maps every live agent's observation to a valid action."""

    name: str

    def reset(self, seed: int | None = None) -> None:
        """Start an episode (per-episode state such as round-robin counters, and the random stream)."""

    def act(self, observations: Mapping[str, Observation]) -> dict[str, Action]:
        """One action per agent in ``observations``; never a masked one."""


# ----- observation helpers -----

def has_decision(obs: Observation) -> bool:
    """True when the agent has at least one task to place (otherwise its action is ignored)."""
    return bool(np.any(np.asarray(obs["task"])[..., TaskField.PRESENT] > 0))


def masks_of(obs: Observation) -> list[np.ndarray]:
    """The action mask of each task slot: one array in binary mode, B in batch mode."""
    mask = obs["action_mask"]
    return [np.asarray(mask)] if isinstance(mask, np.ndarray) else [np.asarray(m) for m in mask]


def is_batch(obs: Observation) -> bool:
    return not isinstance(obs["action_mask"], np.ndarray)


def symlog(x: np.ndarray) -> np.ndarray:
    """sign(x) log(1 + |x|): squashes magnitudes spanning decades (buffers 3..600, rates, seconds)."""
    return np.sign(x) * np.log1p(np.abs(x))


@dataclass(frozen=True)
class AgentSpec:
    """What a network needs to know about one agent: neighbour slots and number of actions."""

    slots: int
    n_actions: int

    @classmethod
    def of(cls, observation_space: spaces.Dict, action_space: spaces.Space) -> AgentSpec:
        if not isinstance(action_space, spaces.Discrete):
            raise ValueError(f"learning agents need binary mode (a Discrete action space), not {action_space}; "
                             "batch mode is supported by the baselines only")
        return cls(slots=observation_space["neighbours"].shape[0], n_actions=int(action_space.n))


def specs_of(env: Any) -> dict[str, AgentSpec]:
    """The spec of every possible agent of a PettingZoo parallel env."""
    return {a: AgentSpec.of(env.observation_space(a), env.action_space(a)) for a in env.possible_agents}


# The columns of ``flatten``'s own and neighbour blocks, in order, and the sizes of its four blocks
OWN_COLUMNS = ("queue", "occupancy", "buffer", "capacity", "undecided", "tier", "fill", "work")
NEIGHBOUR_COLUMNS = ("present", "tier", "queue", "occupancy", "buffer", "capacity", "rate", "age", "fill", "backlog",
                     "work")
OWN_DIM, TASK_DIM, NEIGHBOUR_DIM, ESTIMATE_DIM = len(OWN_COLUMNS), 7, len(NEIGHBOUR_COLUMNS), 4


def flat_dim(slots: int) -> int:
    """Length of ``flatten``'s output for an agent with ``slots`` neighbour slots."""
    return OWN_DIM + TASK_DIM + NEIGHBOUR_DIM * slots + ESTIMATE_DIM * (1 + slots)


def flatten(own: np.ndarray, task: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Observations of N agents with the same slot count -> (N, flat_dim) float32 features.

    Blocks, in order (each documented in docs/agents.md):
      own (8): symlog of queue, occupancy, buffer, capacity [Mcycles/s], undecided; tier; fill = occupancy/buffer;
        symlog of its work left [s]
      task (7): present, cpi, symlog of instructions [M], input [MB], output [MB], time left [s], ticks waited
      neighbours (11 per slot): present, tier, symlog of queue, occupancy, buffer, capacity [Mcycles/s],
        rate [Mbit/s], age [ticks]; fill; symlog of the link's backlog [s] and of the node's work left [s]
      estimates (4 per target: local, then each slot): symlog of the task's wait (the target's work left, as
        last heard), execution and transfer times [s] at that target and of its slack: time to deadline
        minus all of them and the link's backlog (> 0: it should finish in time there); 0 without a task
        or a neighbour. ``greedy`` adds up the same times, but waits the target's queue length times this
        task's execution: where task sizes are mixed the work left is the better guess.
    Magnitudes stay within about [-1, 10] on every bundled scenario, whatever its scale.
    """
    own = own.astype(np.float64)
    task = task.astype(np.float64)
    nb = neighbours.astype(np.float64)
    o = OwnField
    own_buffer = np.maximum(own[:, o.BUFFER], 1.0)
    own_f = np.stack([
        symlog(own[:, o.QUEUE]), symlog(own[:, o.OCCUPANCY]), symlog(own[:, o.BUFFER]),
        symlog(own[:, o.CAPACITY_GCPS] * 1e3), symlog(own[:, o.UNDECIDED]), own[:, o.TIER],
        own[:, o.OCCUPANCY] / own_buffer, symlog(own[:, o.WORK_S]),
    ], axis=1)
    t = TaskField
    present = task[:, t.PRESENT]
    task_f = np.stack([
        present, task[:, t.CPI], symlog(task[:, t.INSTRUCTIONS_G] * 1e3), symlog(task[:, t.INPUT_MB]),
        symlog(task[:, t.OUTPUT_MB]), symlog(task[:, t.TIME_LEFT_S]), symlog(task[:, t.WAITED_TICKS]),
    ], axis=1)
    n = NeighbourField
    nb_present = nb[..., n.PRESENT]
    nb_f = np.stack([
        nb_present, nb[..., n.TIER], symlog(nb[..., n.QUEUE]), symlog(nb[..., n.OCCUPANCY]),
        symlog(nb[..., n.BUFFER]), symlog(nb[..., n.CAPACITY_GCPS] * 1e3), symlog(nb[..., n.RATE_MBPS]),
        symlog(nb[..., n.AGE_TICKS]), nb[..., n.OCCUPANCY] / np.maximum(nb[..., n.BUFFER], 1.0),
        symlog(nb[..., n.BACKLOG_S]), symlog(nb[..., n.WORK_S]),
    ], axis=2)
    # Estimated times of the task at each target, in seconds (capacities in cycles/s, sizes in bits).
    cycles = task[:, t.INSTRUCTIONS_G] * task[:, t.CPI] * 1e9  # (N,)
    bits = (task[:, t.INPUT_MB] + task[:, t.OUTPUT_MB]) * 8e6
    capacity = np.concatenate([own[:, None, o.CAPACITY_GCPS], nb[..., n.CAPACITY_GCPS]], axis=1) * 1e9
    work = np.concatenate([own[:, None, o.WORK_S], nb[..., n.WORK_S]], axis=1)
    rate = nb[..., n.RATE_MBPS] * 1e6
    valid = np.concatenate([np.ones_like(present)[:, None], nb_present], axis=1) * present[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        execution = np.where(valid > 0, cycles[:, None] / capacity, 0.0)
        transfer = np.zeros_like(execution)
        transfer[:, 1:] = np.where(valid[:, 1:] > 0, bits[:, None] / rate, 0.0)
    wait = np.where(valid > 0, work, 0.0)
    backlog = np.concatenate([np.zeros_like(present)[:, None], nb[..., n.BACKLOG_S]], axis=1)
    slack = np.where(valid > 0, task[:, None, t.TIME_LEFT_S] - (wait + execution + transfer + backlog), 0.0)
    est = np.stack([symlog(wait), symlog(execution), symlog(transfer), symlog(slack)], axis=2)
    est = np.nan_to_num(est, nan=0.0, posinf=20.0, neginf=-20.0)
    rows = len(own)
    return np.concatenate([own_f, task_f, nb_f.reshape(rows, -1), est.reshape(rows, -1)], axis=1).astype(np.float32)


def flatten_one(obs: Observation) -> np.ndarray:
    """``flatten`` for one binary-mode observation -> (flat_dim,)."""
    return flatten(obs["own"][None], obs["task"][None], obs["neighbours"][None])[0]


def one_hot(index: int, size: int) -> np.ndarray:
    out = np.zeros(size, dtype=np.float32)
    out[index] = 1.0
    return out


# ----- masked distributions -----

TIE = 1e-4  # values this close to the largest (relative, at least absolute) tie with it: the first wins


def masked_argmax(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Index of the largest value among the allowed actions (masked ones count as -inf), the first of those within
    ``TIE`` of it. Two identical targets score the same in exact arithmetic, but a forward pass rounds a row
    differently with the batch it is in (about 1e-6): without the tolerance the greedy action would depend on how
    many agents decide at once, and the serial and the batched evaluation would part."""
    v = values.masked_fill(~mask, -torch.inf)
    top = v.max(dim=-1, keepdim=True).values
    return (v >= top - TIE * top.abs().clamp(min=1.0)).to(torch.uint8).argmax(dim=-1)


class MaskedCategorical:
    """A categorical over the allowed actions only (masked logits get probability exactly 0).

    Masked logits are set to the most negative finite float rather than -inf, so that log-probabilities
    and the entropy stay finite (0 * -inf would be NaN)."""

    def __init__(self, logits: torch.Tensor, mask: torch.Tensor) -> None:
        self.mask = mask
        self.logits = torch.log_softmax(logits.masked_fill(~mask, torch.finfo(logits.dtype).min), dim=-1)
        self.probs = self.logits.exp()

    def sample(self, generator: torch.Generator | None = None) -> torch.Tensor:
        return torch.multinomial(self.probs, 1, generator=generator).squeeze(-1)

    def mode(self) -> torch.Tensor:
        return masked_argmax(self.logits, self.mask)

    def log_prob(self, actions: torch.Tensor) -> torch.Tensor:
        return self.logits.gather(-1, actions.long().unsqueeze(-1)).squeeze(-1)

    def entropy(self) -> torch.Tensor:
        return -(self.probs * self.logits).masked_fill(~self.mask, 0.0).sum(-1)


# ----- networks, devices, seeds -----

def mlp(n_in: int, hidden: Sequence[int], n_out: int, out_gain: float = 1.0) -> nn.Sequential:
    """A ReLU MLP with orthogonal initialisation (CleanRL's choice); ``out_gain`` scales the last layer."""
    layers: list[nn.Module] = []
    sizes = [n_in, *hidden]
    for a, b in itertools.pairwise(sizes):
        layers += [_init(nn.Linear(a, b), np.sqrt(2)), nn.ReLU()]
    layers.append(_init(nn.Linear(sizes[-1], n_out), out_gain))
    return nn.Sequential(*layers)


class TargetScorer(nn.Module):
    """An actor that scores each target (keep local, then each neighbour slot) with one shared MLP.

    The score of target j is ``mlp([own, task, target_j])``, where target_j holds what ``flatten`` knows of
    that target: the neighbour's block (the node's own numbers, in the same columns, for local), whether it
    is local, and the task's estimates there. The same weights serve every slot, so each decision teaches
    the network about every target it compared, a neighbour learnt in one slot is understood in any
    other, and the policy does not depend on the order of the neighbours or their number: it transfers
    to other degrees and topologies. Any columns after the estimates (the agent id) are not used. An empty
    slot (no neighbour) scores 0: the action mask never allows it.
    """

    def __init__(self, slots: int, hidden: Sequence[int], out_gain: float = 0.01) -> None:
        super().__init__()
        self.slots = slots
        self.score = mlp(OWN_DIM + TASK_DIM + 1 + NEIGHBOUR_DIM + ESTIMATE_DIM, hidden, 1, out_gain)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        lead, s = x.shape[:-1], self.slots
        context = x[..., :OWN_DIM + TASK_DIM]
        start = OWN_DIM + TASK_DIM
        neighbours = x[..., start:start + NEIGHBOUR_DIM * s].reshape(*lead, s, NEIGHBOUR_DIM)
        start += NEIGHBOUR_DIM * s
        estimates = x[..., start:start + ESTIMATE_DIM * (1 + s)].reshape(*lead, 1 + s, ESTIMATE_DIM)
        # the node itself as a target: its own columns where a neighbour has them, present, no link
        own = x[..., :OWN_DIM]
        local = torch.stack([own[..., OWN_COLUMNS.index(c)] if c in OWN_COLUMNS
                             else torch.full_like(own[..., 0], float(c == "present")) for c in NEIGHBOUR_COLUMNS],
                            dim=-1)
        targets = torch.cat([local.unsqueeze(-2), neighbours], dim=-2)  # (..., 1 + S, NEIGHBOUR_DIM)
        is_local = torch.zeros(*lead, 1 + s, 1, dtype=x.dtype, device=x.device)
        is_local[..., 0, :] = 1.0
        rows = torch.cat([context.unsqueeze(-2).expand(*lead, 1 + s, -1), is_local, targets, estimates], dim=-1)
        # only the targets that exist are scored: an empty slot is masked whatever its score (0 here), and with
        # 32 slots for nodes of a few neighbours, scoring them all would be most of the work
        present = targets[..., 0] > 0
        scores = torch.zeros(*lead, 1 + s, dtype=x.dtype, device=x.device)
        scores[present] = self.score(rows[present]).squeeze(-1)
        return scores


def _init(layer: nn.Linear, gain: float) -> nn.Linear:
    nn.init.orthogonal_(layer.weight, gain)
    nn.init.zeros_(layer.bias)
    return layer


def resolve_device(name: str) -> torch.device:
    """``cpu`` (default) or ``cuda``; cuda only when asked for and available (else a warning and the CPU)."""
    if name not in ("cpu", "cuda") and not name.startswith("cuda:"):
        raise ValueError(f"device must be 'cpu' or 'cuda', not {name!r}")
    if name.startswith("cuda") and not torch.cuda.is_available():
        warnings.warn("CUDA is not available: running on the CPU", stacklevel=2)
        return torch.device("cpu")
    return torch.device(name)


def seed_everything(seed: int) -> None:
    """Seed Python, NumPy and torch (weights initialisation); the agents keep their own generators."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def polyak(target: nn.Module, online: nn.Module, tau: float) -> None:
    """target <- tau * online + (1 - tau) * target (tau = 1 is a hard copy)."""
    with torch.no_grad():
        for t, o in zip(target.parameters(), online.parameters(), strict=True):
            t.lerp_(o, tau)
