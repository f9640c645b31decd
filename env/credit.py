"""Per-task credit: the outcome of each task and the congestion it caused, credited to the step that placed it.

A step reward arrives when its events happen, not when the decision that caused them was taken: on a
link where a transfer takes a minute, the charge for a queue a task joined reaches its agent 50-60 steps
after the decision, where a discount of 0.99 and GAE's lambda of 0.95 leave a weight of about 0.03 on it
(docs/agents.md, "Why the wired links needed credit per task"). The nodes' ledger
(``role.Counters.ledger``) names the task of every completion, loss and charge, so the environment can
credit each task's whole account to the decisions that placed it, once it is known:

    credit(task) = [completed] (1 - response / P) - c * (waiting it imposed on others, in their deadlines)

the ``marginal`` reward's two terms for that one task (``reward.timeliness``, c the environment's
``RewardSettings.congestion_price``, P the headline score's penalty). It reaches the agent as
``infos[agent]["credits"]``: (step, credit) pairs, ``step`` counting the episode's steps from 0, one pair per
decision whose every task has settled. A decision whose tasks are still in the network when the episode ends
gets no credit: the episode was cut short, and crediting those tasks as lost (as the headline score counts
them) would teach that whatever is slow near the end is bad, as a truncated return taken for a terminal one
would. A decision on a task that had already settled (it expired while the agent looked at it) is credited 0
at once: nothing it chose changed anything.
A charge that reaches a task after it settled (a lost transfer keeps its link busy) is not credited.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from env.reward import RewardSettings
from node_runtime.model.array import LedgerRows
from node_runtime.model.role import CHARGED, COMPLETED

Credits = dict[str, list[tuple[int, float]]]  # agent -> [(step of the decision, credit)]
# A decision comes at most a few epochs after its task settled (it was in the agent's last observation), so
# only the latest settled tasks need remembering: between this many and twice as many, whatever the
# episode's length, so that memory stays flat in it
SETTLED_MEMORY = 100_000


class TaskCredit:
    """Which decisions placed each task, and what each task has cost so far."""

    def __init__(self, penalty: float, settings: RewardSettings) -> None:
        self.penalty = penalty
        self.settings = settings
        self.reset()

    def reset(self) -> None:
        self._tasks: dict[int, tuple[list[float], list[tuple[str, int]]]] = {}  # id -> ([charges], decisions)
        self._open: dict[tuple[str, int], list[float]] = {}  # (agent, step) -> [tasks unsettled, credit so far]
        self._settled: set[int] = set()  # tasks that settled: the latest ones ...
        self._settled_before: set[int] = set()  # ... and the generation before them

    def place(self, agent: str, step: int, tasks: Iterable[int]) -> Credits:
        """Record a decision; returns its credit at once if all its tasks had settled already."""
        key = (agent, step)
        count = 0
        for task in tasks:
            if task in self._settled or task in self._settled_before:
                continue
            self._tasks.setdefault(task, ([0.0], []))[1].append(key)
            count += 1
        if not count:
            return {agent: [(step, 0.0)]}
        self._open[key] = [count, 0.0]
        return {}

    def settle(self, ledger: Iterable[tuple[int, int, float]]) -> Credits:
        """Apply one tick's ledger; returns the decisions whose every task has now settled."""
        out: Credits = {}
        for task, kind, value in ledger:
            entry = self._tasks.get(task)
            if entry is None:  # a task no agent placed (yet): remember that it is gone
                if kind != CHARGED:
                    self._forget_after(task)
                continue
            if kind == CHARGED:
                entry[0][0] += value
                continue
            timely = 1.0 - value / self.penalty if kind == COMPLETED else 0.0
            self._close(task, timely, out)
        return out

    def _close(self, task: int, timely: float, out: Credits) -> None:
        charges, decisions = self._tasks.pop(task)
        credit = timely - self.settings.congestion_price * charges[0]
        self._forget_after(task)
        for key in decisions:
            left = self._open[key]
            left[0] -= 1
            left[1] += credit
            if left[0] == 0:
                del self._open[key]
                out.setdefault(key[0], []).append((key[1], left[1]))

    def _forget_after(self, task: int) -> None:
        """Remember that ``task`` settled, forgetting the oldest generation of settled tasks when full."""
        self._settled.add(task)
        if len(self._settled) >= SETTLED_MEMORY:
            self._settled_before, self._settled = self._settled, set()


class ArrayCredit:
    """``TaskCredit`` for the K copies of an array batch at once, task by task: each task's credit once it has
    settled, in arrays indexed as the batch's tasks are (copy, task index). A decision in binary mode places one
    task, so its credit is its task's; a decision on a task that had settled already is credited 0 at once,
    charges before a task's first placement and after it settled are not counted, exactly as ``TaskCredit``
    does (tests/test_vector_ppo.py compares the two on the same episodes)."""

    def __init__(self, penalty: float, settings: RewardSettings) -> None:
        self.penalty = penalty
        self.settings = settings
        self.reset(0, 0)

    def reset(self, k: int, m: int) -> None:
        """A new episode of K copies of at most ``m`` tasks each."""
        self.placed = np.zeros((k, m), dtype=bool)
        self.settled = np.zeros((k, m), dtype=bool)
        self.charges = np.zeros((k, m))
        self.credit = np.full((k, m), np.nan)  # NaN until the task settles (or for a task no decision placed)

    def place(self, copy: np.ndarray, task: np.ndarray) -> np.ndarray:
        """Record decisions on tasks (copy, task index); returns which of them had settled already (credit 0)."""
        done = self.settled[copy, task]
        self.placed[copy[~done], task[~done]] = True
        return done

    def settle(self, rows: LedgerRows) -> None:
        """Apply one tick's ledger, entry after entry as ``TaskCredit.settle`` does, in arrays."""
        if not len(rows.copy):
            return
        m = self.placed.shape[1]
        key = rows.copy * m + rows.task
        ends = np.flatnonzero(rows.kind != CHARGED)
        # the first entry that settles each task this tick (each task ends once; a later one would change nothing)
        end_keys, first = np.unique(key[ends], return_index=True)
        end_at = ends[first]
        live = self.placed[rows.copy, rows.task] & ~self.settled[rows.copy, rows.task]
        first_end = np.full(len(key), len(key))  # each entry's task's first ending entry this tick (none: len)
        at = np.searchsorted(end_keys, key)
        hit = at < len(end_keys)
        hit[hit] = end_keys[at[hit]] == key[hit]
        first_end[hit] = end_at[at[hit]]
        counted = np.flatnonzero((rows.kind == CHARGED) & live & (np.arange(len(key)) < first_end))
        np.add.at(self.charges, (rows.copy[counted], rows.task[counted]), rows.value[counted])
        closing = end_at[live[end_at]]
        c, i = rows.copy[closing], rows.task[closing]
        timely = np.where(rows.kind[closing] == COMPLETED, 1.0 - rows.value[closing] / self.penalty, 0.0)
        self.credit[c, i] = timely - self.settings.congestion_price * self.charges[c, i]
        self.settled[rows.copy[end_at], rows.task[end_at]] = True
