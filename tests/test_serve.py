"""`orchestrator launch --serve`: environments attach from other processes and drive the clock.

The same serving runs on the in-process bus too (no router, no process), through the same
Transport interface: describe, claim, release, a vanished driver.
"""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest

from env import ZenohEdgeEnv
from node_runtime.runtime.answers import AnswerError, claim_answer, session_answer
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.protocol import Tick
from node_runtime.runtime.transport import TransportError
from node_runtime.runtime.zenoh_bus import ZenohTransport, free_port
from orchestrator import serve
from orchestrator.clock import ClockError
from orchestrator.serve import Busy, claim, describe, session_of
from orchestrator.session import Simulation
from tests.conftest import model_part, run_summary
from tests.launcher import Launch, assert_all_gone, claiming_driver, served


def play(env, seed, steps, actions_seed=0):
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(actions_seed)
    rewards = []
    for _ in range(steps):
        actions = {a: int(rng.choice(np.flatnonzero(obs[a]["action_mask"]))) for a in env.agents}
        obs, r, *_ = env.step(actions)
        rewards.append(r)
    return obs, rewards, env.summary()


@pytest.mark.zenoh
def test_attach_drive_detach_and_stop(tmp_path):
    run = Launch("aot1", "--serve", "--episodes", "1", "--steps", "30", "--layout", "per-node", "--out", str(tmp_path))
    run.wait_for("serving until Ctrl-C")
    children = run.descendants()
    endpoint, sim = served(run)

    env = ZenohEdgeEnv(connect=endpoint, sim_id=sim, max_steps=40)
    assert env.scenario.name == "aot1" and len(env.possible_agents) == 10
    obs, rewards, summary = play(env, seed=7, steps=40)

    # while it holds the clock, nobody else can take it
    other = ZenohEdgeEnv(connect=endpoint, sim_id=sim)
    with pytest.raises(Busy, match="held by driver/"):
        other.reset(seed=1)
    other.close()
    env.close()

    # the attached episode is the emulation a local run gives for the same seed and actions
    local = ZenohEdgeEnv("aot1", transport="inproc", max_steps=40)
    local_obs, local_rewards, local_summary = play(local, seed=7, steps=40)
    local.close()
    assert rewards == local_rewards
    assert all(np.array_equal(obs[a][k], local_obs[a][k]) for a in obs for k in obs[a])
    assert {k: v for k, v in summary.items() if k != "run"} == {k: v for k, v in local_summary.items() if k != "run"}

    # the clock is free again after close: a second driver gets it, with a later episode number
    again = ZenohEdgeEnv(connect=endpoint, sim_id=sim, max_steps=5)
    again.reset(seed=2)
    assert again.sim.clock.episode == 2  # 0: the server's own episode, 1: the first driver's
    again.close()

    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(30) == 130
    assert_all_gone(children)


@pytest.mark.zenoh
def test_a_claim_ends_with_its_driver(tmp_path):
    """A driver killed (SIGKILL) or exiting without releasing held the clock of a served simulation for good."""
    run = Launch("aot1", "--serve", "--episodes", "1", "--steps", "5", "--out", str(tmp_path))
    run.wait_for("serving until Ctrl-C")
    endpoint, sim = served(run)
    killed, name = claiming_driver(endpoint, sim, "hold")
    assert describe(endpoint, sim)["driver"] == name
    killed.proc.send_signal(signal.SIGKILL)
    run.wait_for(f"driver {name} left without releasing the clock (its liveliness token vanished")
    killed.proc.wait(10)

    left, name = claiming_driver(endpoint, sim, "exit")  # the clock is free again: a second driver gets it
    assert left.proc.wait(30) == 0
    run.wait_for(f"driver {name} left without releasing the clock")
    again = Simulation.attach(endpoint, sim)  # and a third
    again.close()
    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(30) == 130
    control = json.loads((tmp_path / "summary.json").read_text())["run"]["control"]
    assert control == {"granted": 3, "released": 1, "vanished": 2, "refused_claims": 0, "refused_releases": 0}


@pytest.mark.zenoh
def test_serving_refuses_garbage_and_counts_every_refusal(tmp_path):
    """An empty query on …/control raised a traceback in the orchestrator (and got no reply); refused releases
    were counted but reported nowhere."""
    run = Launch("aot1", "--serve", "--episodes", "1", "--steps", "5", "--out", str(tmp_path))
    run.wait_for("serving until Ctrl-C")
    endpoint, sim = served(run)
    keys = Keys(sim)
    asker = ZenohTransport.client(endpoint)
    try:
        replies = {what: [(r.ok is None, r.err.payload.to_bytes().decode() if r.err else "")
                          for r in asker.session.get(key, payload=payload, timeout=10)]
                   for what, key, payload in (("empty", keys.control(), None),
                                              ("garbage", keys.control(), b"\xc1garbage"),
                                              ("a number", keys.control(), b"\x07"),  # msgpack's 7
                                              ("empty session", keys.session(), None))}
        refused = {what: [err for err, _ in r] for what, r in replies.items()}
        assert refused == {"empty": [True], "garbage": [True], "a number": [True], "empty session": [False]}, replies
        assert "an empty request" in replies["empty"][0][1]
        holder = Simulation.attach(asker, sim)  # the clock is held: a release from anyone else is refused
        outsider = ZenohTransport.client(endpoint)
        answer = outsider.request(keys.control(), {"type": "control", "release": holder.attached, "episode": 1,
                                                   "epoch": holder.clock.epoch}, 10)
        assert answer["released"] is False
        with pytest.raises(Busy):
            claim(outsider, keys, 10)
        outsider.close()
        holder.close()  # closes ``asker`` too
    finally:
        asker.close()
    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(30) == 130
    assert not [line for line in run.err if "Traceback" in line], "".join(run.err)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["run"]["control"] == {"granted": 1, "released": 1, "vanished": 0, "refused_claims": 1,
                                         "refused_releases": 1}
    assert summary["run"]["rejected_messages"]["orchestrator"] == {"bad_msgpack": 1, "clock_taken": 1,
                                                                   "not_holder": 1, "wrong_shape": 2}


def test_serving_over_the_in_process_bus(aot1):
    with Simulation.inproc(aot1) as served_sim:
        bus, keys = served_sim.transport.bus, served_sim.keys
        served_sim.run(10, seed=5)  # the server's own episode 0
        info = session_of(bus.endpoint(), keys, 1.0)
        assert {k: info[k] for k in ("type", "sim", "layout", "episode", "driver", "procs", "placement")} == {
            "type": "session", "sim": keys.sim_id, "layout": "single", "episode": 0, "driver": None,
            "procs": ["all"], "placement": {}}
        assert info["scenario"]["name"] == "aot1" and len(info["scenario"]["nodes"]) == 12

        with pytest.raises(Busy, match="not serving"):  # outside `accepting`, the clock stays the server's
            Simulation.attach(bus.endpoint(), keys.sim_id)
        with served_sim.server.accepting():
            driver = Simulation.attach(bus.endpoint(), keys.sim_id)
            assert session_of(bus.endpoint(), keys, 1.0)["driver"] == driver.attached
            with pytest.raises(Busy, match=f"held by {driver.attached}"):
                Simulation.attach(bus.endpoint(), keys.sim_id)
            # the driver's name is public; releasing needs the token only the claimant received
            outsider = bus.endpoint()
            for forged in ({"release": driver.attached}, {"release": driver.attached, "token": "0" * 32},
                           {"release": driver.attached, "token": 7}):
                forged = {"type": "control", "episode": 99, "epoch": driver.clock.epoch, **forged}
                answer = outsider.request(keys.control(), forged, 1.0)
                assert answer["released"] is False
            stale = {"type": "control", "release": driver.attached, "token": driver._secret, "episode": 99,
                     "epoch": driver.clock.epoch - 1}  # the holder's token, another epoch
            assert outsider.request(keys.control(), stale, 1.0)["released"] is False
            assert served_sim.server.counts["refused_releases"] == 4
            assert session_of(outsider, keys, 1.0)["driver"] == driver.attached
            summary = driver.run(40, seed=7)
            assert driver.clock.episode == 1
            driver.close()
            assert session_of(bus.endpoint(), keys, 1.0)["driver"] is None

            # a driver that vanishes without releasing: the server takes the clock back
            lost = bus.endpoint()
            _, name, _, _ = claim(lost, keys, 1.0)  # its liveliness token goes up first
            assert session_of(bus.endpoint(), keys, 1.0)["driver"] == name
            lost.close()
            assert session_of(bus.endpoint(), keys, 1.0)["driver"] is None
            assert served_sim.server.counts["vanished"] == 1
        served_sim.reset(seed=1)
        assert served_sim.clock.episode == 2  # numbered after the driver's episode
        # the released driver still holds the clock's key of its epoch: its ticks are refused now, as is a stop
        # without any key; the served simulation runs on
        former = bus.endpoint()
        former.publish(keys.tick(), Tick(9, 1, "stop", epoch=driver.clock.epoch), driver.clock.keyring.clock_key(
            driver.clock.epoch))
        former.publish(keys.tick(), Tick(served_sim.clock.episode, 1, "stop"))
        assert served_sim.step().tick == 1
        assert served_sim.drivers[0].rejections.counts == {"bad_mac": 1, "stale_epoch": 1}
        assert served_sim.transport.rejections.counts["stale_epoch"] == 1  # the stale release
    assert model_part(summary) == model_part(run_summary(aot1, 40, seed=7))  # attached: the same emulation


def test_a_claim_without_its_drivers_token_ends(aot1, monkeypatch):
    """A bare claim (no liveliness token ever declared) locked a served simulation for good."""
    monkeypatch.setattr(serve, "TOKEN_GRACE_S", 0.0)  # its claim ends at the first look after the grant
    with Simulation.inproc(aot1) as served_sim, served_sim.server.accepting():
        keys, bare = served_sim.keys, served_sim.transport.bus.endpoint()
        answer = bare.request(keys.control(), {"type": "control", "claim": "driver/bare"}, 1.0)
        assert answer["granted"] is True
        driver = Simulation.attach(served_sim.transport.bus.endpoint(), keys.sim_id)  # the bare claim is gone
        assert served_sim.server.counts == {"granted": 2, "released": 0, "vanished": 1, "refused_claims": 0,
                                            "refused_releases": 0}
        driver.close()


def test_malformed_requests_get_an_error_and_are_counted(aot1):
    """Requests that are no claim, release or session request: each refused with a reason, none raises."""
    with Simulation.inproc(aot1) as served_sim:
        keys, asker = served_sim.keys, served_sim.transport.bus.endpoint()
        # (what is no map, or no msgpack at all, cannot cross this bus: test_serving_refuses_garbage sends it)
        bad = [(keys.control(), {"type": "control"}), (keys.control(), {"type": "control", "claim": 7}),
               (keys.control(), {"type": "control", "claim": "driver/x", "release": "driver/x"}),
               (keys.control(), {"type": "control", "claim": "x/../y"}),
               (keys.control(), {"type": "control", "release": "driver/x", "episode": "9"}),
               (keys.session(), {"type": "session"})]
        for key, message in bad:
            with pytest.raises(TransportError, match="refused the request"):
                asker.request(key, message, 1.0)
        assert served_sim.transport.rejections.counts == {"wrong_shape": len(bad)}
        asker.request(keys.control(), {"type": "control", "release": "driver/x", "token": "0" * 32, "episode": 1,
                                       "epoch": 0}, 1.0)
        with pytest.raises(Busy, match="not serving"):
            claim(asker, keys, 1.0)
        summary = served_sim.run(5)
    assert summary["run"]["rejected_messages"]["orchestrator"] == {"clock_taken": 1, "not_holder": 1,
                                                                   "wrong_shape": len(bad)}
    assert summary["run"]["control"] == {"granted": 0, "released": 0, "vanished": 0, "refused_claims": 1,
                                         "refused_releases": 1}


ROGUE_ANSWERS = {  # what an outsider's queryable answered, and what the driver did with it before
    "a session description without a valid scenario (a bare KeyError)":
        ("session", lambda sim: {"type": "session", "sim": sim, "scenario": {"name": "x"}, "layout": "single",
                                 "episode": 0, "driver": None, "procs": ["all"], "placement": {}}),
    "a refused claim (the clock denied for good)":
        ("control", lambda sim: {"type": "control", "granted": False, "reason": "the clock is held by driver/rogue"}),
    "a grant at an earlier episode (the driver hung, blaming the nodes)":
        ("control", lambda sim: {"type": "control", "granted": True, "episode": -1, "token": "0" * 32}),
}


@pytest.mark.zenoh
def test_a_rogue_answer_on_session_or_control_is_refused(tmp_path):
    """A driver believed the first answer to its queries. Now it asks every session that serves the key; when
    an outsider's queryable answers too, the driver refuses with one line naming the key and both sessions,
    whatever the outsider says; once the outsider is gone, the driver attaches and runs."""
    run = Launch("aot1", "--serve", "--episodes", "1", "--steps", "3", "--out", str(tmp_path))
    run.wait_for("serving until Ctrl-C")
    endpoint, sim = served(run)
    keys = Keys(sim)
    for what, (kind, answer) in ROGUE_ANSWERS.items():
        rogue = ZenohTransport.client(endpoint)
        key = keys.session() if kind == "session" else keys.control()
        rogue.serve(key, lambda message, answer=answer: answer(sim))
        rogue_id = str(rogue.session.zid())
        try:
            with pytest.raises(ClockError) as refused:
                Simulation.attach(endpoint, sim, timeout=10)
        finally:
            rogue.close()
        line = str(refused.value)
        assert f"{key} was answered by 2 Zenoh sessions" in line and rogue_id in line, (what, line)
        assert "\n" not in line
    with Simulation.attach(endpoint, sim, timeout=10) as driver:  # the outsider is gone: the real answers alone
        driver.run(5, seed=3)
        assert driver.clock.episode == 1
    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(30) == 130
    # the server granted the two contested claims too: their drivers' liveliness tokens went with them
    assert json.loads((tmp_path / "summary.json").read_text())["run"]["control"] == {
        "granted": 3, "released": 1, "vanished": 2, "refused_claims": 0, "refused_releases": 0}


def test_answers_of_the_wrong_shape_are_one_line(aot1):
    """When whoever alone answers for a simulation id gives an answer of the wrong shape, the driver says which
    field is wrong: never a KeyError, and never an episode below what the session description said."""
    with Simulation.inproc(aot1) as served_sim:
        keys = served_sim.keys
        good = session_of(served_sim.transport.bus.endpoint(), keys, 1.0)
    for field, value, says in (("scenario", {"name": "x"}, "scenario or layout does not validate"),
                               ("layout", "diagonal", "scenario or layout does not validate"),
                               ("episode", 2**40, "field 'episode'"), ("procs", "all", "field 'procs'"),
                               ("sim", "another", "simulation 'another'"), ("type", "tick", "not a session")):
        with pytest.raises(AnswerError, match=says):
            session_answer({**good, field: value}, keys.session())
    with pytest.raises(AnswerError, match="field 'placement'"):
        session_answer({k: v for k, v in good.items() if k != "placement"}, keys.session())
    keys32 = bytes(range(32))
    grant = {"type": "control", "granted": True, "episode": 4, "token": "ab" * 16,
             "keys": {"epoch": 2, "clock": keys32, "procs": {"all": keys32}, "hosts": {}}}
    assert claim_answer(grant, keys.control(), 4) == grant
    for answer, says in (({**grant, "episode": 3}, "episode 3, where the session said 4"),
                         ({**grant, "token": None}, "without a token"), ({**grant, "granted": 1}, "neither"),
                         ({**grant, "keys": {**grant["keys"], "clock": b"short"}}, "without the keys of its epoch"),
                         ({"type": "control", "granted": False, "reason": 7}, "reason is not text")):
        with pytest.raises(AnswerError, match=says):
            claim_answer(answer, keys.control(), 4)


def test_connect_requires_the_sim_id():
    with pytest.raises(ValueError, match="sim_id"):
        ZenohEdgeEnv(connect="tcp/127.0.0.1:1")


@pytest.mark.zenoh
def test_an_endpoint_where_no_router_answers_or_no_endpoint_at_all_is_named():
    """They were Zenoh's own errors, with a path into its Rust sources."""
    port = free_port()  # nothing listens on it
    with pytest.raises(TransportError, match=rf"^cannot reach tcp/127\.0\.0\.1:{port}: no Zenoh router answers there$"):
        ZenohEdgeEnv(connect=f"tcp/127.0.0.1:{port}", sim_id="abc", timeout=2)
    with pytest.raises(TransportError, match=rf"^cannot reach tcp/127\.0\.0\.1:{port}: no Zenoh router answers there$"):
        Simulation.attach(f"tcp/127.0.0.1:{port}", "abc")
    with pytest.raises(TransportError, match=r"^'localhost:7447' is no Zenoh endpoint: expected <protocol>/<address>"):
        ZenohEdgeEnv(connect="localhost:7447", sim_id="abc", timeout=2)


@pytest.mark.zenoh
def test_a_router_on_every_interface_is_advertised_at_addresses_a_client_can_reach(tmp_path):
    """--listen 0.0.0.0 (with --insecure, since there is no --security) says where other hosts reach it, never
    the wildcard, which no client can connect to; loopback comes last. Only loopback is used here."""
    from orchestrator.serve import describe

    port = free_port("0.0.0.0")
    run = Launch("aot1", "--serve", "--episodes", "0", "--layout", "groups:1", "--listen", f"0.0.0.0:{port}",
                 "--insecure")
    run.wait_for("serving until Ctrl-C")
    text = "".join(run.err)
    assert "warning: --insecure: plain TCP on 0.0.0.0" in text
    endpoint, sim = served(run)
    assert endpoint == f"tcp/0.0.0.0:{port}"
    addresses = text.split("(reached at ", 1)[1].split(")", 1)[0].split(", ")
    assert addresses[-1] == f"tcp/127.0.0.1:{port}" and not any("0.0.0.0" in a for a in addresses)
    assert f"--connect {addresses[0]} --sim {sim}" in text and f'ZenohEdgeEnv(connect="{addresses[0]}"' in text
    assert describe(addresses[-1], sim)["scenario"]["name"] == "aot1"
    run.proc.send_signal(signal.SIGINT)
    assert run.finish(60) == 130
