"""``ZenohEdgeVectorEnv``: K in-process simulations stepped as one TorchRL batch.

    from env.vector import ZenohEdgeVectorEnv
    env = ZenohEdgeVectorEnv("aot2", num_envs=4, max_steps=300)     # batch_size (4,)
    td = env.rollout(1000, break_when_any_done=False)               # (4, 1000); each sim resets on its own

TorchRL's ``PettingZooWrapper`` turns every agent's observation, reward and info number into a tensor
one by one, which costs about four times the simulation itself (docs/env.md, "Speed"). This env is
native to TorchRL instead: each ``ZenohEdgeEnv(observation="flat", transport="inproc")`` yields NumPy
arrays, which are stacked over agents and simulations and become one tensor per key per step. The keys
and shapes are those of ``PettingZooWrapper(use_mask=True, categorical_actions=True)`` with all agents in
one group "agents", with a leading K axis, so code written against the wrapper (the MAPPO example) runs
on it unchanged. To use several cores, put it in TorchRL's ``ParallelEnv``: each worker then steps K
simulations.

With ``backend="array"`` the K simulations are the K copies of one array program (docs/array.md), stepped
together in one call per tick, and each copy's ``ZenohEdgeEnv`` reads its copy as it would read its own
simulation: the same observations, rewards and infos as K in-process environments with the same seeds
and actions. Its copies start their episodes together (every episode has the same length, so they also end
together); a reset that names only some of them is refused. Two paths make its tensors (``path`` says which
one a setting takes): "batched" (the default where it covers the setting: ``env.batched`` computes every
copy's observations, masks, rewards and info numbers at once from the backend's arrays, and nothing of the
copies' own environments runs) or "per-copy" (each copy's ``ZenohEdgeEnv`` reads its copy: any reward, any
setting, their ``step_details`` and ``summary()``; ``env.batched.uncovered`` says why a setting takes it).

Optional dependency: ``pip install -e ".[marl]"`` (TorchRL).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from env.batched import BatchedSteps, uncovered
from env.environment import ZenohEdgeEnv
from orchestrator.array_session import ArrayBatch

GROUP = "agents"


class ZenohEdgeVectorEnv(EnvBase):
    """K flat-observation simulations of one scenario, stepped together in this process.

    Args:
        scenario: as for ``ZenohEdgeEnv``.
        num_envs: K, the number of simulations (the env's ``batch_size`` is ``(K,)``).
        seed: simulation k's first episode is seeded ``seed + k`` (as after ``set_seed(seed)``); without
            one, the K seeds start from fresh entropy, still one apart.
        info_numbers: put the flat infos under ``("agents", "info", key)`` (one (K, N) tensor per number).
        backend: "emulator" (K in-process simulations of the node code) or "array" (one array program of K
            copies; docs/env.md, "Backends").
        batched: with the array backend, None (default): the batched path where it covers the setting, else the
            per-copy path; True: the batched path or a ``ValueError`` saying what it does not cover; False: the
            per-copy path.
        **kwargs: any other ``ZenohEdgeEnv`` argument but ``observation``, ``transport`` and ``connect``
            (flat and in-process here), e.g. ``max_steps``, ``reward``, ``overrides``.

    In batch mode (B tasks placed per step) each agent's action and mask gain a B axis before the last.
    ``set_seed(s)`` seeds simulation k with ``s + k``; its later episodes draw their seeds from that
    stream, exactly as one ``ZenohEdgeEnv`` seeded with ``s + k`` does.
    """

    def __init__(self, scenario: Any = "aot1", *, num_envs: int = 1, seed: int | None = None,
                 info_numbers: bool = True, backend: str = "emulator", batched: bool | None = None,
                 **kwargs: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, not {num_envs!r}")
        for fixed in ("observation", "transport", "connect"):
            if fixed in kwargs:
                raise TypeError(f"ZenohEdgeVectorEnv is flat and in-process: {fixed}= cannot be given")
        super().__init__(batch_size=torch.Size([num_envs]), allow_done_after_reset=False)
        self.envs = [ZenohEdgeEnv(scenario, observation="flat", backend=backend, transport="inproc",
                                  info_numbers=info_numbers, **kwargs) for _ in range(num_envs)]
        first = self.envs[0]
        self.agent_names = list(first.possible_agents)
        self.group_map = {GROUP: self.agent_names}
        self._seeds: list[int | None] = [None] * num_envs
        self._started = False  # the first reset resets every simulation, whatever it is asked
        self._make_specs(first, info_numbers)
        self.batch: ArrayBatch | None = None
        self.batched: BatchedSteps | None = None
        self.path = "per-copy"  # how the tensors are made: "batched" (array backend only) or "per-copy"
        if backend == "array":  # one program of K copies: each env reads its copy as its simulation
            self.batch = ArrayBatch(first.scenario, num_envs, first.episode_ticks)
            for env, copy in zip(self.envs, self.batch.copies, strict=True):
                env.sim = copy
            reason = uncovered(first)
            if batched and reason is not None:
                raise ValueError(f"the batched array path does not cover {reason}")
            if batched is not False and reason is None:
                self.batched = BatchedSteps(first, self.batch, self._info_keys)
                self.path = "batched"
        elif batched:
            raise ValueError("batched=True needs backend='array'")
        # every simulation's first reset gets its seed explicitly (the spec probe above reset the first one)
        self._set_seed(int(np.random.SeedSequence().entropy % 2**31) if seed is None else seed)

    # ----- specs -----

    def _make_specs(self, env: ZenohEdgeEnv, info_numbers: bool) -> None:
        """The specs, and the arrays each step's simulations write their rows into."""
        k, n = self.batch_size[0], len(self.agent_names)
        space = env.observation_space(self.agent_names[0])
        dim = space["observation"].shape[0]
        *slots, actions = space["action_mask"].shape  # slots: () in binary mode, (B,) in batch mode
        _, infos = env.reset(seed=0)  # the info keys are only known from a reset
        self._info_keys = list(infos[self.agent_names[0]]) if info_numbers else []
        self._observation = np.zeros((k, n, dim), dtype=np.float32)
        self._mask = np.zeros((k, n, *slots, actions), dtype=bool)
        self._info = np.zeros((k, n, len(self._info_keys)), dtype=np.float32)
        group = {
            "observation": Composite(observation=Unbounded((k, n, dim), dtype=torch.float32), shape=(k, n)),
            "action_mask": Binary(n=actions, shape=(k, n, *slots, actions), dtype=torch.bool),
            "mask": Binary(n=n, shape=(k, n), dtype=torch.bool),
        }
        if self._info_keys:
            group["info"] = Composite({key: Unbounded((k, n), dtype=torch.float32) for key in self._info_keys},
                                      shape=(k, n))
        self.observation_spec = Composite({GROUP: Composite(group, shape=(k, n))}, shape=(k,))
        self.action_spec = Composite(
            {GROUP: Composite(action=Categorical(actions, shape=(k, n, *slots), dtype=torch.int64), shape=(k, n))},
            shape=(k,))
        self.reward_spec = Composite({GROUP: Composite(reward=Unbounded((k, n, 1)), shape=(k, n))}, shape=(k,))
        flags = {f: Categorical(2, shape=(k, n, 1), dtype=torch.bool) for f in ("done", "terminated", "truncated")}
        self.done_spec = Composite({
            GROUP: Composite(flags, shape=(k, n)),
            **{f: Categorical(2, shape=(k, 1), dtype=torch.bool) for f in ("done", "terminated", "truncated")},
        }, shape=(k,))

    # ----- TorchRL API -----

    def _set_seed(self, seed: int | None) -> None:
        self._seeds = [None if seed is None else seed + i for i in range(len(self.envs))]

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        which = self._to_reset(tensordict)
        self._started = True
        if self.batch is not None:
            return self._reset_batch(which)
        for i in np.flatnonzero(which):
            observations, infos = self.envs[i].reset(seed=self._seeds[i])
            self._seeds[i] = None  # later episodes draw from the stream that seed started
            self._write(i, observations, infos)
        return self._output(ended=np.zeros(len(self.envs), dtype=bool))

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get((GROUP, "action")).cpu().numpy()
        if self.batched is not None:
            self._observation, self._mask, rewards, ended, self._info = self.batched.step(actions, self._mask)
            out = self._output(ended=np.full(len(self.envs), ended))
            out.set((GROUP, "reward"), torch.from_numpy(rewards.astype(np.float32)).unsqueeze(-1))
            return out
        rewards = np.zeros((len(self.envs), len(self.agent_names)), dtype=np.float32)
        ended = np.zeros(len(self.envs), dtype=bool)
        steps = self._step_batch(actions) if self.batch is not None else (
            env.step(dict(zip(self.agent_names, actions[i].tolist(), strict=True))) for i, env in enumerate(self.envs))
        for i, (observations, reward, _, truncations, infos) in enumerate(steps):
            self._write(i, observations, infos)
            rewards[i] = [reward[a] for a in self.agent_names]
            ended[i] = truncations[self.agent_names[0]]  # every agent's episode ends at the same step
        out = self._output(ended=ended)
        out.set((GROUP, "reward"), torch.from_numpy(rewards).unsqueeze(-1))
        return out

    def close(self, *, raise_if_closed: bool = True) -> None:
        for env in self.envs:
            env.close()
        super().close(raise_if_closed=raise_if_closed)

    # ----- the array backend: K copies, one call per tick -----

    def _reset_batch(self, which: np.ndarray) -> TensorDictBase:
        """Start an episode in every copy, each with the seed its own environment would take."""
        if not which.all():
            raise ValueError("the array backend resets all its copies together (they end together): "
                             f"asked to reset {int(which.sum())} of {len(which)}")
        seeds = [env._episode_seed(seed) for env, seed in zip(self.envs, self._seeds, strict=True)]
        self._seeds = [None] * len(self.envs)
        if self.batched is not None:
            self._observation, self._mask, self._info = self.batched.reset(seeds)
            return self._output(ended=np.zeros(len(self.envs), dtype=bool))
        reports = self.batch.reset(seeds, external=self.envs[0]._driven())
        for i, (env, report) in enumerate(zip(self.envs, reports, strict=True)):
            self._write(i, *env._started(report))
        return self._output(ended=np.zeros(len(self.envs), dtype=bool))

    def _step_batch(self, actions: np.ndarray) -> list[tuple]:
        """Each environment's step, its actions placed before and its reports read after the batch's ticks."""
        placed = [env._place(dict(zip(self.agent_names, actions[i].tolist(), strict=True)))
                  for i, env in enumerate(self.envs)]
        ticks = [self.batch.step([p.controller_actions for p in placed])]
        for _ in range(self.envs[0].scenario.decision_interval - 1):
            ticks.append(self.batch.step([None] * len(self.envs)))
        return [env._stepped(p, [tick[i] for tick in ticks])
                for i, (env, p) in enumerate(zip(self.envs, placed, strict=True))]

    # ----- internals -----

    def _to_reset(self, tensordict: TensorDictBase | None) -> np.ndarray:
        """Which simulations to reset: all at the first reset, else those TorchRL's "_reset" flags name."""
        everyone = np.ones(len(self.envs), dtype=bool)
        if tensordict is None or not self._started:
            return everyone
        flag = tensordict.get("_reset", None)
        if flag is None:
            flag = tensordict.get((GROUP, "_reset"), None)
            if flag is None:
                return everyone
            flag = flag.flatten(1).any(-1)
        return flag.reshape(len(self.envs)).cpu().numpy()

    def _write(self, i: int, observations: dict[str, dict[str, np.ndarray]], infos: dict[str, dict[str, float]]
               ) -> None:
        """Simulation i's latest observations, masks and info numbers, into its row of the batch."""
        for j, agent in enumerate(self.agent_names):
            self._observation[i, j] = observations[agent]["observation"]
            self._mask[i, j] = observations[agent]["action_mask"]
            if self._info_keys:
                self._info[i, j] = [infos[agent][key] for key in self._info_keys]

    def _output(self, *, ended: np.ndarray) -> TensorDictBase:
        """The batch as tensors: copies of the per-copy path's arrays, since its next step overwrites them (the
        batched path makes new ones every step)."""
        k, n = len(self.envs), len(self.agent_names)
        own = (lambda a: a) if self.batched is not None else np.copy
        observation = torch.from_numpy(own(self._observation))
        mask = torch.from_numpy(own(self._mask))
        truncated = torch.from_numpy(ended).reshape(k, 1)
        group: dict[str, Any] = {
            "observation": TensorDict({"observation": observation}, batch_size=(k, n)),
            "action_mask": mask,
            "mask": torch.ones(k, n, dtype=torch.bool),
            "done": truncated.unsqueeze(1).expand(k, n, 1).clone(),
            "terminated": torch.zeros(k, n, 1, dtype=torch.bool),
            "truncated": truncated.unsqueeze(1).expand(k, n, 1).clone(),
        }
        if self._info_keys:
            numbers = torch.from_numpy(own(self._info))  # (k, n, keys)
            group["info"] = TensorDict({key: numbers[..., j] for j, key in enumerate(self._info_keys)},
                                       batch_size=(k, n))
        return TensorDict({GROUP: TensorDict(group, batch_size=(k, n)), "done": truncated.clone(),
                           "terminated": torch.zeros(k, 1, dtype=torch.bool), "truncated": truncated.clone()},
                          batch_size=(k,))
