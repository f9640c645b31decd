"""The clock opens the next tick ahead for the processes that cannot get actions (``Clock.open_next``), so
they run while the agents decide; that changes when a tick runs, never what it computes."""

from __future__ import annotations

from dataclasses import astuple

import numpy as np
import pytest

from env import ZenohEdgeEnv
from node_runtime.model.role import role_id
from orchestrator.clock import ClockError
from orchestrator.session import Simulation
from tests.conftest import model_part, same
from tests.test_env import masked_random
from tests.test_sleeping import driven_scenarios

EPISODE = 150


def drive(sim: Simulation, ahead: bool, seed: int = 4) -> list:
    """An episode in which every controller with tasks keeps its first one (action 0); ``ahead``: the clock
    opens each next tick early for the processes holding no such controller, as the environment does."""
    controllers = [role_id("controller", n.id) for n in sim.scenario.nodes if "controller" in n.roles]
    reports = [astuple(sim.reset(seed, external=controllers))]
    for _ in range(EPISODE):
        with_tasks = [role for role, obs in sim.seen.items() if obs.tasks]
        if ahead:
            sim.clock.open_next(hold=with_tasks)
        reports.append(astuple(sim.step(dict.fromkeys(with_tasks, 0))))
    return reports


@pytest.mark.parametrize("layout", ["per-node", "per-role"])
def test_opening_ahead_gives_the_same_ticks(aot2, layout):
    """In-process the opened processes run inside the publication, so their reports come before ``step``:
    the clock must take them as the next tick's, and nothing may differ."""
    runs = []
    for ahead in (False, True):
        with Simulation.inproc(aot2, layout=layout) as sim:
            runs.append((drive(sim, ahead), model_part(sim.summary()), sim.summary()["run"]["rejected_messages"]))
    (plain, plain_summary, _), (early, early_summary, rejected) = runs
    assert same(plain_summary, early_summary)
    for t, (a, b) in enumerate(zip(plain, early, strict=True)):
        assert same(a, b), f"tick {t} differs"
    assert rejected == {"orchestrator": {}, "nodes": {}}


def test_actions_for_a_process_opened_ahead_are_refused(aot2):
    with Simulation.inproc(aot2, layout="per-node") as sim:
        controllers = [role_id("controller", n) for n in aot2.controllers]
        sim.reset(1, external=controllers)
        sim.clock.open_next()  # holds nobody back
        ahead = [c for c in controllers if sim.clock.actors[c] in sim.clock.early]
        assert ahead
        with pytest.raises(ClockError, match="opened ahead"):
            sim.step({ahead[0]: 0})


def test_a_reset_after_opening_ahead_takes_that_ticks_reports_first(aot2):
    with Simulation.inproc(aot2, layout="per-node") as sim:
        drive(sim, ahead=True)
        sim.clock.open_next()
        assert sim.clock.early
        again = drive(sim, ahead=False, seed=4)
        assert not sim.clock.early
        assert sim.summary()["run"]["rejected_messages"] == {"orchestrator": {}, "nodes": {}}
    with Simulation.inproc(aot2, layout="per-node") as sim:
        assert all(same(a, b) for a, b in zip(drive(sim, ahead=False, seed=4), again, strict=True))


@pytest.mark.zenoh
def test_over_zenoh_a_reset_mid_episode_leaves_nothing_behind():
    """Over Zenoh the processes opened ahead are still running when ``reset`` comes: their reports are
    awaited, none is refused as stale, and the new episode is the one a fresh environment runs."""
    episodes = []
    for transport in ("inproc", "zenoh"):
        env = ZenohEdgeEnv("aot2", transport=transport, layout="per-node", max_steps=EPISODE)
        rng = np.random.default_rng(2)
        obs, _ = env.reset(seed=7)
        for _ in range(20):
            obs, *_ = env.step(masked_random(env, obs, rng))
        obs, _ = env.reset(seed=8)
        trace = [obs]
        for _ in range(40):
            obs, rewards, *_ = env.step(masked_random(env, obs, rng))
            trace.append((obs, rewards))
        episodes.append((trace, model_part(env.summary()), env.summary()["run"]["rejected_messages"]))
        env.close()
    (ref, ref_summary, _), (got, got_summary, rejected) = episodes
    assert rejected == {"orchestrator": {}, "nodes": {}}
    assert same(ref_summary, got_summary)
    assert all(same(a, b) for a, b in zip(ref, got, strict=True))


@pytest.mark.zenoh
@pytest.mark.parametrize("name", ["tricky", "failures", "co-located"])
def test_over_zenoh_epochs_failures_and_colocated_control_give_the_in_process_episode(tmp_path, name):
    """Decision epochs of 3 ticks (ticks without actions between two steps), batch mode, sparse broadcasts;
    failures of neighbours and of the agent's own node; control latency 0: the ticks opened ahead still
    give, step for step, the episode of the in-process run."""
    scenario = driven_scenarios(tmp_path)[name]
    episodes = []
    for transport, layout in (("inproc", "single"), ("zenoh", "per-node")):
        env = ZenohEdgeEnv(scenario, transport=transport, layout=layout, max_steps=60)
        rng = np.random.default_rng(1)
        obs, _ = env.reset(seed=3)
        trace = [obs]
        while env.agents:
            obs, rewards, _, _, infos = env.step(masked_random(env, obs, rng))
            trace.append((obs, rewards, {a: i["credits"] for a, i in infos.items()}))
        episodes.append((trace, model_part(env.summary())))
        env.close()
    (ref, ref_summary), (got, got_summary) = episodes
    assert same(ref_summary, got_summary)
    assert all(same(a, b) for a, b in zip(ref, got, strict=True))
