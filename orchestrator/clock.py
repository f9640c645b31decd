"""The simulated clock: the orchestrator's side of the barrier protocol (docs/protocol.md).

``step`` opens tick t with ``Tick(t, expect)``, where ``expect[p]`` is the number of publications
the processes reported sending to ``p`` in tick t - 1, and returns once every process it opened the
tick for has reported ``Done(t)``. It opens it only for the processes that have mail from tick t - 1
or said in their last ``Done`` that they have work at t: the others sleep, and their last reports
stand. A reset opens tick 0 for all. A process that reports an error, dies, or stays silent past the
timeout ends the run with an error that names it and the nodes it hosted.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from node_runtime.runtime.keys import Keys
from node_runtime.runtime.layout import ProcessLayout
from node_runtime.runtime.protocol import Done, Tick
from node_runtime.runtime.transport import Transport


class ClockError(RuntimeError):
    pass


class ProcessFailed(ClockError):
    def __init__(self, proc: str, nodes: tuple[str, ...], why: str) -> None:
        what = f"node {nodes[0]}" if len(nodes) == 1 else f"nodes {', '.join(nodes)}"
        super().__init__(f"process {proc} ({what}) {why}")
        self.proc = proc
        self.nodes = nodes


class Clock:
    def __init__(self, transport: Transport, keys: Keys, plan: ProcessLayout, timeout: float = 30.0,
                 health: Callable[[], None] | None = None) -> None:
        self.transport = transport
        self.keys = keys
        self.plan = plan
        self.procs = plan.procs
        self.timeout = timeout
        self.health = health
        self.episode = -1
        self.latest = -1  # the highest episode run or seen on the bus (another driver may have run some)
        self.tick = -1
        self.expect: dict[int, int] = {}  # process index -> publications to wait for
        self.wake: list[int | None] = [None] * len(self.procs)  # process index -> next tick with work of its own
        self.actors = {role: plan.proc_index[plan.proc_of[role]] for role in plan.roles}
        self.tick_keys = [keys.tick(p) for p in self.procs]  # process index -> its own tick key
        self.dones: dict[str, Done] = {}
        transport.subscribe(keys.done(), self.on_done)

    def on_done(self, key: str, done: Done) -> None:
        self.latest = max(self.latest, done.episode)
        if done.error is not None:
            first = done.error.strip().splitlines()[0]
            raise ProcessFailed(done.proc, self.plan.node_of_proc(done.proc), f"failed in tick {done.tick}: {first}"
                                ) from RuntimeError(done.error)
        if done.episode == self.episode and done.tick == self.tick:
            self.dones[done.proc] = done

    def reset(self, seed: int, external: list[str] | None = None, policy: str | None = None) -> list[Done]:
        """Start a new episode: every process resets its roles, then runs tick 0."""
        self.episode = max(self.episode, self.latest) + 1
        self.latest = self.episode
        self.tick = 0
        self.dones = {}
        self.transport.publish(self.keys.tick(), Tick(self.episode, 0, "reset", seed=seed,
                                                      external=list(external or ()), policy=policy))
        return self._collect(range(len(self.procs)))

    def step(self, actions: dict[str, Any] | None = None) -> list[Done]:
        """Run the next tick; ``actions`` go to externally driven controllers."""
        self.tick += 1
        t = self.tick
        mine: dict[int, dict[str, Any]] = {}  # process index -> actions for its controllers
        for role, action in (actions or {}).items():
            mine.setdefault(self.actors[role], {})[role] = action
        expect = self.expect
        opened = [i for i, wake in enumerate(self.wake)
                  if i in expect or i in mine or (wake is not None and wake <= t)]
        self.dones = {}
        if len(opened) == len(self.procs):  # one publication reaches them all
            self.transport.publish(self.keys.tick(), Tick(self.episode, t, "run", expect, actions or {}))
        else:
            for i in opened:
                self.transport.publish(self.tick_keys[i], Tick(
                    self.episode, t, "run", {i: expect[i]} if i in expect else {}, mine.get(i, {})))
        return self._collect(opened)

    def catch_up(self, episode: int) -> None:
        """Another driver ran episodes up to ``episode``: number ours after them."""
        self.latest = max(self.latest, episode)

    def stop(self) -> None:
        self.transport.publish(self.keys.tick(), Tick(self.episode, self.tick + 1, "stop"))

    def _collect(self, opened: Sequence[int]) -> list[Done]:
        """Wait for the Done of every process the tick was opened for, in canonical order."""
        n = len(opened)
        try:
            self.transport.dispatch(until=lambda: len(self.dones) == n, timeout=self.timeout, idle=self.health)
        except TimeoutError:
            silent = [self.procs[i] for i in opened if self.procs[i] not in self.dones]
            nodes = sorted({nd for p in silent for nd in self.plan.node_of_proc(p)})
            raise ClockError(f"tick {self.tick}: no report within {self.timeout:.0f} s from "
                             f"{', '.join(silent[:8])}{' ...' if len(silent) > 8 else ''} "
                             f"(nodes {', '.join(nodes[:8])})") from None
        dones = [self.dones[self.procs[i]] for i in opened]
        expect: dict[int, int] = {}
        for i, d in zip(opened, dones, strict=True):
            self.wake[i] = d.wake
            for p, count in d.sent.items():
                expect[p] = expect.get(p, 0) + count
        self.expect = expect
        return dones
