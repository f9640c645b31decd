"""``ZenohEdgeEnv(backend="array")`` gives the in-process environment's steps, step for step.

Both environments run the same scenario with the same seed; every step both get the same actions, drawn
from one random stream among the choices the (reference) action masks allow. After the reset and every
step the observations (masks included), rewards, terminations, truncations and infos (the node counters,
the reward terms, the per-task credits, the episode's summary at the end) must be equal: exactly, floats
included, since the array backend adds its floats in the emulator's order. CI runs a small set;
``--all`` runs aot1-aot4 and the other bundled scenarios the backend takes over whole episodes, and more
settings, link loss, results relayed along paths (``max_hops`` above 1), ``queue_first``, ``control_latency: 0``
and failures. Deliberately broken rules (a deadline one tick late, a tick's ledger reversed, a lost message kept
out of the ledger, a co-located controller reading its worker as heard, ``queue_first``'s list miscounted or
reported on every decision, a controller back from a failure forgetting its worker's last report or observing
while down) must make the comparison fail.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from env import ZenohEdgeEnv
from env.overrides import ScenarioOverrides
from node_runtime.model import array
from node_runtime.model.array import NONE, ArraySim, Unsupported, refusal
from node_runtime.model.spec import Scenario
from orchestrator.array_session import ArrayBatch
from orchestrator.scenario import load_scenario
from tests.conftest import same
from tests.test_array_backend import with_failures
from topologies import bundled_scenarios


def draw(rng: np.random.Generator, obs: dict[str, Any]) -> dict[str, Any]:
    """An action per agent, among those its mask allows (one per task slot in batch mode)."""
    actions = {}
    for agent, o in obs.items():
        mask = o["action_mask"]
        if isinstance(mask, tuple) or mask.ndim == 2:
            actions[agent] = [int(rng.choice(np.flatnonzero(m))) for m in mask]
        else:
            actions[agent] = int(rng.choice(np.flatnonzero(mask)))
    return actions


def first_difference(scenario: Any, seed: int, steps: int, actions_seed: int = 0, policy: str | None = None,
                     **kwargs: Any) -> str | None:
    """Step both environments (``policy``: the node-side policy of the controllers no agent drives); where they
    first differ (step, what, agent), or None."""
    envs = [ZenohEdgeEnv(scenario, seed=seed, backend=backend, transport="inproc", max_steps=steps, **kwargs)
            for backend in ("emulator", "array")]
    rng = np.random.default_rng(actions_seed)
    try:
        results = [env.reset(options={"policy": policy} if policy else None) for env in envs]
        for step in range(steps + 1):
            names = ("observations", "rewards", "terminations", "truncations", "infos")[-len(results[0]):]
            for what, mine, theirs in zip(names, results[1], results[0], strict=True):
                if not same(mine, theirs):
                    agent = next((a for a in theirs if not same(mine.get(a), theirs[a])), None)
                    return f"step {step}: {what} of {agent}: {mine.get(agent)!r} != {theirs.get(agent)!r}"
            if step == steps:
                return None
            actions = draw(rng, results[0][0])
            results = [env.step(actions) for env in envs]
    finally:
        for env in envs:
            env.close()


def lossy(name: str, loss: float, **changes: Any) -> Scenario:
    """``name`` with every link losing each message with probability ``loss`` (and ``changes``)."""
    sc = load_scenario(name)
    return sc.replace(links=[dataclasses.replace(lk, loss=loss) for lk in sc.links], **changes)


# (scenario, seed, steps, environment arguments): aot1-aot4, aot4 with lossy links and results relayed
# along paths of up to 3 hops, aot2_reference (queue_first, control_latency 0), examples/failures, then settings
# beyond the bundled ones, agents driving some controllers only (the others with a node-side policy), link loss,
# max_hops 2, queue_first, control_latency 0 and failures each alone and with the others; CI runs the first seven
SMALL = [("aot1", 3, 120, {}), ("aot2", 7, 100, {}), ("aot3", 2, 80, {}), ("aot4", 5, 60, {}),
         (lossy("aot4", 0.1, max_hops=3), 3, 80, {"reward": "marginal"}),
         ("aot2_reference", 3, 120, {"reward": "marginal"}),
         ("examples/failures", 1, 120, {"reward": "marginal"}),
         ("aot1_urgent", 4, 100, {"reward": "marginal"}),
         ("aot2", 1, 60, {"overrides": ScenarioOverrides(mode="batch", batch_size=3), "observation": "flat"}),
         ("aot2", 2, 60, {"overrides": ScenarioOverrides(decision_interval=3), "reward": "team"}),
         ("aot3", 3, 80, {"agents": ["rpi3_0", "rpi3_2", "rpi3_4"], "policy": "least_queue"}),
         ("aot2", 4, 60, {"overrides": ScenarioOverrides(mode="batch", batch_size=2, decision_interval=2),
                          "reward": "marginal", "neighbour_slots": 20}),
         (lossy("aot2", 0.1), 3, 100, {}),
         (lossy("aot4", 0.2), 5, 60, {"reward": "marginal", "observation": "flat"}),
         (load_scenario("aot2").replace(max_hops=2), 2, 100, {"reward": "marginal"}),
         (load_scenario("aot2").replace(max_hops=2, mode="batch", batch_size=3), 4, 80,
          {"reward": "marginal", "agents": ["rpi3_0", "rpi3_2", "rpi3_4"], "policy": "random"}),
         ("aot3", 5, 80, {"agents": ["rpi3_1", "rpi3_3"], "policy": "drift_plus_penalty", "reward": "marginal"}),
         ("aot4_reference", 2, 300, {"reward": "marginal"}),
         (load_scenario("aot2").replace(admission="queue_first"), 2, 200, {"reward": "marginal"}),
         (lossy("aot4", 0.1, max_hops=3, admission="queue_first"), 5, 300, {"reward": "marginal"}),
         (load_scenario("aot3").replace(admission="queue_first", decision_interval=2, state_interval=3), 3, 150,
          {"reward": "paper"}),
         (load_scenario("aot2").replace(admission="queue_first", mode="batch", batch_size=3), 1, 120,
          {"observation": "flat", "agents": ["rpi3_0", "rpi3_2", "rpi3_4"], "policy": "greedy_backlog"}),
         (load_scenario("aot1_urgent").replace(control_latency=0), 4, 300, {"reward": "marginal"}),
         (load_scenario("aot2").replace(control_latency=0, mode="batch", batch_size=3), 1, 150,
          {"observation": "flat"}),
         (load_scenario("aot2").replace(control_latency=0, decision_interval=3, state_interval=2), 2, 100,
          {"reward": "team"}),
         (load_scenario("aot3").replace(control_latency=0), 3, 150,
          {"agents": ["rpi3_0", "rpi3_2", "rpi3_4"], "policy": "greedy_backlog", "reward": "paper"}),
         (lossy("aot4", 0.1, max_hops=3, admission="queue_first", control_latency=0, mode="batch", batch_size=2), 6,
          300, {"reward": "marginal"}),
         (with_failures("aot2", 3, ((30, 20), (120, 7))), 3, 200, {"reward": "marginal"}),
         (with_failures("aot2_reference", 2, ((60, 2), (150, 1))), 3, 200, {"reward": "marginal"}),
         (with_failures("aot2", 3, ((30, 20), (120, 7))).replace(admission="queue_first"), 4, 200,
          {"reward": "marginal"}),
         (with_failures("aot2", 3, ((30, 20), (120, 7))).replace(control_latency=0), 5, 200, {"reward": "paper"}),
         (with_failures("aot2", 3, ((30, 20), (120, 7))).replace(decision_interval=3, state_interval=2), 3, 100,
          {"reward": "marginal"}),
         (with_failures("aot2", 3, ((0, 5), (31, 20), (120, 7))).replace(mode="batch", batch_size=3), 2, 200,
          {"observation": "flat", "agents": ["rpi3_0", "rpi3_3", "rpi3_4"], "policy": "least_queue"})]
CI = 7


def case_id(value: Any) -> str | None:
    if isinstance(value, Scenario):  # a changed scenario: what was changed
        base = load_scenario(value.name)
        changed = [("-loss", any(lk.loss for lk in value.links)), (f"-hops{value.max_hops}", value.max_hops > 1),
                   ("-queue_first", value.admission != base.admission),
                   ("-colocated", value.control_latency != base.control_latency),
                   ("-failures", value.failures != base.failures)]
        return value.name + "".join(tag for tag, yes in changed if yes)
    return value if isinstance(value, str) else None


@pytest.mark.parametrize(("name", "seed", "steps", "kwargs"), SMALL, ids=case_id)
def test_the_array_env_steps_as_the_inprocess_env(name, seed, steps, kwargs, request):
    if [case[1:] for case in SMALL].index((seed, steps, kwargs)) >= CI and not request.config.getoption("--all"):
        pytest.skip("the full set runs with --all")
    assert first_difference(name, seed, steps, **kwargs) is None


def full_set() -> list[str]:
    return [name for name in bundled_scenarios() if refusal(load_scenario(name)) is None]


@pytest.mark.slow
@pytest.mark.parametrize("name", full_set())
def test_every_bundled_scenario_it_takes_over_a_whole_episode(name, request):
    if not request.config.getoption("--all"):
        pytest.skip("the full set runs with --all")
    sc = load_scenario(name)
    assert first_difference(name, 1, sc.steps, reward="marginal") is None


def test_a_deadline_one_tick_late_is_caught(monkeypatch):
    """The comparison can fail: with every task expiring one tick late the array env differs."""
    expiry = array.expiry_tick
    monkeypatch.setattr(array, "expiry_tick", lambda created, size, dt: expiry(created, size, dt) + 1)
    assert first_difference("aot1_urgent", 4, 100) is not None


def test_a_ledger_out_of_order_is_caught(monkeypatch):
    """Credits follow the ledger's order: the array backend's entries of a tick reversed are caught."""
    settle = array.ArraySim._settle_ledger

    def reversed_ledger(self):
        settle(self)
        self.ledger = [entries[::-1] for entries in self.ledger]

    monkeypatch.setattr(array.ArraySim, "_settle_ledger", reversed_ledger)
    found = first_difference("aot2", 7, 100, reward="marginal")
    assert found is not None and "credits" in found


def test_a_lost_message_kept_out_of_the_ledger_is_caught(monkeypatch):
    """A message lost on its link is a loss of its task in the worker's ledger, and its credits follow."""
    drop = ArraySim._drop

    def unrecorded_loss(self, c, i, roles, cause, key=0):
        recording, self.recording = self.recording, self.recording and cause != "link_loss"
        drop(self, c, i, roles, cause, key)
        self.recording = recording

    monkeypatch.setattr(ArraySim, "_drop", unrecorded_loss)
    found = first_difference(lossy("aot4", 0.1, max_hops=3), 3, 80, reward="marginal")
    assert found is not None and "credits" in found


def test_a_colocated_controller_reading_its_worker_as_heard_is_caught(monkeypatch):
    """control_latency 0: the driven controller observes its own worker and links as they are at the end of the
    tick; reading its own state as broadcast (a tick old), or its links as last reported, is caught."""
    remember = ArraySim._remember_view
    sc = load_scenario("aot2").replace(control_latency=0)

    def as_broadcast(self, t):
        remember(self, t)
        self.seen_own = self.seen_heard, self.seen_occupancy, self.seen_drain

    def as_reported(self, t):
        remember(self, t)
        self.seen_busy = self.told_busy.copy()

    for broken in (as_broadcast, as_reported):
        with monkeypatch.context() as m:
            m.setattr(ArraySim, "_remember_view", broken)
            assert "observations" in (first_difference(sc, 7, 100) or "")


def test_queue_first_shown_as_undecided_or_reported_on_decisions_is_caught(monkeypatch):
    """queue_first: the tasks a driven controller may place are its worker's divertible ones as last reported, and
    the worker reports when that list changes, not on every decision: counting its undecided tasks instead, or a
    report (with the links' backlogs) on every decision, is caught."""
    remember, decisions = ArraySim._remember_view, ArraySim._decisions

    def undecided(self, t):
        remember(self, t)
        self.seen_undecided = self.undecided.copy()

    def reported(self, t):
        c, i = self.decided.get(t, (NONE, NONE))
        self.bumped[c, self.dec_node[c, i]] = True
        decisions(self, t)

    sc = lossy("aot4", 0.1, max_hops=3, admission="queue_first")
    for name, broken in (("_remember_view", undecided), ("_decisions", reported)):
        with monkeypatch.context() as m:
            m.setattr(ArraySim, name, broken)
            assert "observations" in (first_difference(sc, 3, 80, reward="marginal") or "")


def test_a_controller_back_from_a_failure_or_down_seen_otherwise_is_caught(monkeypatch):
    """Failures: a driven controller whose node is down observes nothing (the empty observation), and one back up
    first sees its worker's last report from before the failure (tasks the failure dropped, and how many it
    held); forgetting that report, or its count, or observing while down, is caught."""
    fail, observations = ArraySim._fail, ArrayBatch.observations

    def forgets(self, t):
        fail(self, t)
        self.ghosts.clear()

    def miscounts(self, t):
        fail(self, t)
        self.ghost_count[:] = 0

    def observes_while_down(self, copy):
        with monkeypatch.context() as m:
            m.setattr(self.sim, "down", np.zeros_like(self.sim.down))
            return observations(self, copy)

    for owner, name, broken in ((ArraySim, "_fail", forgets), (ArraySim, "_fail", miscounts),
                                (ArrayBatch, "observations", observes_while_down)):
        with monkeypatch.context() as m:
            m.setattr(owner, name, broken)
            assert "observations" in (first_difference("examples/failures", 1, 120) or "")


def test_pettingzoo_parallel_api():
    env = ZenohEdgeEnv("aot2", backend="array", max_steps=30)
    parallel_api_test(env, num_cycles=20)
    env.close()


def test_what_the_backend_does_not_model_is_refused_in_one_line():
    """The environment refuses, in one line, what the array backend refuses (here a client whose tasks cross the
    radio), with agents as without."""
    reason = refusal(load_scenario("examples/zigzag_workload"))
    assert reason is not None
    with pytest.raises(Unsupported) as info:
        ZenohEdgeEnv("examples/zigzag_workload", backend="array")
    assert str(info.value) == reason and "\n" not in reason and "in-process or Zenoh backend" in reason


def test_a_backend_it_does_not_know_is_refused():
    with pytest.raises(ValueError, match="backend must be 'emulator'"):
        ZenohEdgeEnv("aot2", backend="jax")


def vector_difference(name: str, k: int, steps: int, max_steps: int, batched: bool | None = None,
                      any_action: bool = False, **kwargs: Any) -> str | None:
    """``ZenohEdgeVectorEnv`` over the array backend (``batched``: its path, as the env's argument) against K
    in-process simulations, through episode ends (each resets when done): where their tensors first differ, or
    None. The actions are drawn among those the masks allow, or with ``any_action`` among all (masked choices
    then stay local and count as invalid)."""
    import torch

    from env.vector import GROUP, ZenohEdgeVectorEnv

    envs = [ZenohEdgeVectorEnv(name, num_envs=k, seed=11, max_steps=max_steps, **kwargs),
            ZenohEdgeVectorEnv(name, num_envs=k, seed=11, backend="array", batched=batched, max_steps=max_steps,
                               **kwargs)]
    assert envs[1].path == ("per-copy" if batched is False else "batched")
    rng = np.random.default_rng(0)
    try:
        tds = [env.reset() for env in envs]
        for step in range(steps):
            for key in tds[0].keys(include_nested=True, leaves_only=True):
                if not torch.equal(tds[0].get(key), tds[1].get(key)):
                    return f"step {step}: {key}"
            mask = tds[0].get((GROUP, "action_mask")).numpy()
            allowed = np.ones_like(mask) if any_action else mask
            action = torch.from_numpy(np.apply_along_axis(lambda m: rng.choice(np.flatnonzero(m)), -1, allowed))
            outs = []
            for j, (env, td) in enumerate(zip(envs, tds, strict=True)):
                td.set((GROUP, "action"), action.clone())
                out, tds[j] = env.step_and_maybe_reset(td)  # the next step acts on what this one observed
                outs.append(out.get("next"))
            for key in outs[0].keys(include_nested=True, leaves_only=True):
                if not torch.equal(outs[0].get(key), outs[1].get(key)):
                    return f"step {step}: next {key}"
        return None
    finally:
        for env in envs:
            env.close()


def test_the_array_vector_env_steps_as_k_inprocess_envs():
    """The per-copy path: each copy's ZenohEdgeEnv reads its copy."""
    pytest.importorskip("torchrl")
    assert vector_difference("aot1", 2, 30, 12, batched=False) is None


# (scenario, copies, steps, episode length, arguments) of the batched path against K in-process environments,
# every reward it computes and the settings it covers; CI runs the first four
OUTAGES = ((0, 5), (12, 9), (30, 4))  # every third node down in ticks 0-4, 12-20 and 30-33
VECTOR = [("aot1", 2, 30, 12, {"any_action": True}),
          ("aot2", 2, 25, 10, {"reward": "marginal", "any_action": True}),
          ("aot2_reference", 2, 25, 10, {"reward": "paper", "any_action": True}),
          (with_failures("aot2", 3, OUTAGES), 2, 40, 16, {"reward": "paper", "any_action": True}),
          ("aot3", 3, 25, 10, {"reward": "sparse"}), ("aot4", 2, 20, 8, {"reward": "team_score"}),
          ("aot1_urgent", 2, 40, 15, {"reward": "score", "any_action": True}),
          ("aot2", 2, 20, 8, {"overrides": ScenarioOverrides(mode="batch", batch_size=3), "any_action": True}),
          ("aot2", 2, 20, 8, {"overrides": ScenarioOverrides(decision_interval=3), "reward": "team"}),
          ("aot3", 2, 20, 8, {"agents": ["rpi3_0", "rpi3_2", "rpi3_4"], "reward": "score"}),
          ("aot2", 2, 20, 8, {"overrides": ScenarioOverrides(mode="batch", batch_size=2, decision_interval=2),
                              "reward": "marginal", "neighbour_slots": 20, "any_action": True}),
          ("aot4", 2, 20, 8, {"reward": "paper", "info_numbers": False, "any_action": True}),
          (load_scenario("aot4").replace(admission="queue_first"), 2, 20, 8, {"reward": "team_score"}),
          (load_scenario("aot2").replace(control_latency=0, mode="batch", batch_size=2), 2, 20, 8,
           {"reward": "paper", "any_action": True}),
          (with_failures("aot2", 3, OUTAGES).replace(admission="queue_first", control_latency=0), 2, 40, 16,
           {"reward": "team_score"}),
          (with_failures("aot2", 3, OUTAGES).replace(mode="batch", batch_size=2, decision_interval=2), 2, 40, 16,
           {"reward": "marginal", "any_action": True})]
VECTOR_CI = 4


@pytest.mark.parametrize(("name", "k", "steps", "max_steps", "kwargs"), VECTOR,
                         ids=lambda v: v if isinstance(v, str) else None)
def test_the_batched_vector_env_steps_as_k_inprocess_envs(name, k, steps, max_steps, kwargs, request):
    pytest.importorskip("torchrl")
    if VECTOR.index((name, k, steps, max_steps, kwargs)) >= VECTOR_CI and not request.config.getoption("--all"):
        pytest.skip("the full set runs with --all")
    assert vector_difference(name, k, steps, max_steps, **kwargs) is None


@pytest.mark.slow
@pytest.mark.parametrize("name", full_set())
def test_the_batched_vector_env_on_every_bundled_scenario_it_takes(name, request):
    if not request.config.getoption("--all"):
        pytest.skip("the full set runs with --all")
    pytest.importorskip("torchrl")
    assert vector_difference(name, 2, 30, 12, reward="marginal", any_action=True) is None


def test_a_broken_rule_of_the_batched_path_is_caught(monkeypatch):
    """The comparison can fail: a task's time left one tick shorter than it is, marginal's delta taken over the
    network rather than the agent's node, a co-located controller's own node read as broadcast, or an agent whose
    node is down shown anything but the empty observation, make the batched env differ."""
    pytest.importorskip("torchrl")
    from env import batched

    sizes = batched.BatchedSteps._sizes

    def shorter(self):
        sizes(self)
        self.size[..., 4] -= self.sim.dt  # every deadline, as the observation shows it

    with monkeypatch.context() as m:
        m.setattr(batched.BatchedSteps, "_sizes", shorter)
        assert "observation" in (vector_difference("aot2", 2, 10, 8) or "")
    with monkeypatch.context() as m:
        m.setattr(batched, "REWARDS", {**batched.REWARDS, batched.marginal_reward: "network"})
        assert "reward" in (vector_difference("aot2", 2, 10, 8, reward="marginal") or "")
    remember = ArraySim._remember_view

    def own_as_broadcast(self, t):  # control_latency 0: its own node as heard, not as it is
        remember(self, t)
        self.seen_own = self.seen_heard, self.seen_occupancy, self.seen_drain

    with monkeypatch.context() as m:
        m.setattr(ArraySim, "_remember_view", own_as_broadcast)
        assert "observation" in (vector_difference("aot2_reference", 2, 10, 8) or "")
    layout = batched.BatchedSteps._layout

    def down_seen_as_up(self, env):  # an agent whose node is down sees its static features, not the empty row
        layout(self, env)
        self.id0 = 0

    with monkeypatch.context() as m:
        m.setattr(batched.BatchedSteps, "_layout", down_seen_as_up)
        assert "observation" in (vector_difference(with_failures("aot2", 3, OUTAGES), 2, 10, 8) or "")


def test_what_the_batched_path_does_not_cover_takes_the_per_copy_path_or_is_refused():
    pytest.importorskip("torchrl")
    from env.vector import ZenohEdgeVectorEnv

    assert ZenohEdgeVectorEnv("aot1", num_envs=2, backend="array", max_steps=5, reward="reference").path == "per-copy"
    with pytest.raises(ValueError, match="batched array path does not cover reward reference") as info:
        ZenohEdgeVectorEnv("aot1", num_envs=2, backend="array", max_steps=5, reward="reference", batched=True)
    assert "\n" not in str(info.value)
