"""The model's equations against values computed by hand."""

from __future__ import annotations

import math

import pytest

from node_runtime.model.energy import compute_energy, idle_energy, transmit_energy
from node_runtime.model.messages import LONGEST_DEADLINE_TICKS, Task, TaskSize
from node_runtime.model.radio import LinkTransmitter, dbm_to_watts, log_distance_gain_db, shannon_rate


def test_shannon_rate_hand_computed():
    # P = 20 dBm, G = -80 dB, w0 = -90 dBm -> SNR = 10^(30/10) = 1000; B = 2 MHz.
    # r = 2e6 * log2(1001) = 2e6 * 9.967226258835993 bit/s
    assert shannon_rate(2e6, 20.0, -80.0, -90.0) == pytest.approx(19_934_452.517671986, rel=1e-12)


def test_zero_db_snr_gives_bandwidth():
    # SNR 0 dB = 1 -> log2(2) = 1 -> r = B
    assert shannon_rate(1e6, 10.0, -50.0, -40.0) == pytest.approx(1e6)


def test_shannon_rate_past_the_floats_range_of_snr():
    # P + G - w0 = 2000 + 2000 - (-100) = 4100 dB: 10^410 overflows a float, but log2(1 + 10^410) is
    # 410 * log2(10) = 1361.98... to double precision, so r = 1e6 * 1361.98... bit/s
    assert shannon_rate(1e6, 2000.0, 2000.0, -100.0) == pytest.approx(1e6 * 410 * math.log2(10), rel=1e-12)
    # at the switch both forms agree: 3000 dB by the formula, and just past it by the asymptote
    assert shannon_rate(1.0, 3000.0, 0.0, 0.0) == pytest.approx(300 * math.log2(10), rel=1e-12)
    assert shannon_rate(1.0, 3000.0, 1e-9, 0.0) == pytest.approx(300 * math.log2(10), rel=1e-12)


def test_log_distance_path_loss():
    # PL(100 m) = 40 + 10 * 3 * log10(100 / 1) = 40 + 60 = 100 dB -> gain -100 dB
    assert log_distance_gain_db(100.0, 40.0, 1.0, 3.0) == pytest.approx(-100.0)
    # closer than the reference distance: the reference loss
    assert log_distance_gain_db(0.2, 40.0, 1.0, 3.0) == pytest.approx(-40.0)


def test_dbm_to_watts():
    assert dbm_to_watts(20.0) == pytest.approx(0.1)
    assert dbm_to_watts(30.0) == pytest.approx(1.0)


def test_transfer_over_an_idle_link_takes_max_1_ceil_b_over_r_dt():
    # 150 MiB = 1,258,291,200 bits at 30 Mbit/s = 41.94 s -> 42 ticks of 1 s, 84 ticks of 0.5 s
    bits = 150 * 1024 * 1024 * 8
    assert LinkTransmitter(30e6, 1.0).send(100, bits)[0] == 100 + 42
    assert LinkTransmitter(30e6, 0.5).send(100, bits)[0] == 100 + 84
    # a tiny message still takes one tick: nothing arrives in the tick it was sent
    assert LinkTransmitter(1e9, 1.0).send(100, 8)[0] == 101


def test_link_fifo_queues_messages():
    link = LinkTransmitter(rate_bps=8e6, dt=1.0)  # 1 MB/s
    # 2 MB at tick 5: on air 5.0 -> 7.0, delivered at tick 7
    assert link.send(5, 16e6) == (7, 2.0, [])
    # 1 MB sent in the same tick waits for the first: 7.0 -> 8.0, delivered at 8
    assert link.send(5, 8e6) == (8, 1.0, [])  # the first was not charged: no delay imposed is counted
    # 0.5 MB at tick 10 (link idle since 8.0): 10.0 -> 10.5, delivered at 11
    assert link.send(10, 4e6) == (11, 0.5, [])


def test_link_counts_the_wait_that_each_charged_message_imposes():
    """Each later message waits for the airtime the charged ones (offloads, by task id) still have ahead of it."""
    link = LinkTransmitter(rate_bps=8e6, dt=0.5)  # 1 MB/s; a tick is half a second
    assert link.send(2, 16e6, charged=1) == (6, 2.0, [])  # ticks 2.0 -> 6.0
    assert link.send(2, 8e6, charged=2) == (8, 1.0, [(1, 2.0)])  # 6.0 -> 8.0; waits the first's 2 s
    # at tick 5: the first has 1 tick (0.5 s) left, the second all its 2 ticks (1 s)
    assert link.send(5, 8e6) == (10, 1.0, [(1, 0.5), (2, 1.0)])
    # at tick 7 the first is done and the second has 1 tick left; an uncharged one ahead imposes nothing
    assert link.send(7, 8e6, charged=3) == (12, 1.0, [(2, 0.5)])
    assert link.send(11, 8e6) == (14, 1.0, [(3, 0.5)])  # only the last charged one is still ahead: 1 tick
    link.reset()
    assert link.send(11, 8e6) == (13, 1.0, [])


def test_link_fifo_with_sub_second_ticks():
    link = LinkTransmitter(rate_bps=1e6, dt=0.25)
    # 0.6 s of airtime = 2.4 ticks: 4.0 -> 6.4, delivered at tick 7
    assert link.send(4, 0.6e6) == (7, 0.6, [])


def test_energy_models():
    # kappa * cycles * f^2 = 1e-27 * 8e7 * (4e6)^2 = 1.28e-6 J
    assert compute_energy(1e-27, 8e7, 4e6) == pytest.approx(1.28e-6)
    assert idle_energy(2.5, 0.5) == pytest.approx(1.25)
    # 20 dBm = 0.1 W for 42 s = 4.2 J
    assert transmit_energy(20.0, 42.0) == pytest.approx(4.2)


def test_task_expiry_is_strictly_after_the_deadline():
    task = Task(1, "a", created=10, size=TaskSize(1, 1, 1, 1, 4.0))
    assert not task.expired(14, 1.0)  # age 4 s == deadline: still valid
    assert task.expired(15, 1.0)
    assert not task.expired(18, 0.5)  # age 4 s
    assert task.expired(19, 0.5)
    assert task.size.cycles == 1


def test_execution_time_is_cycles_over_capacity():
    # rho * xi / (N * phi): 8e7 instructions * 1.5 cpi on 2 cores of 3e7 -> 2 s
    task = Task(1, "a", 0, TaskSize(8e7, 1, 1, 1.5, 100))
    assert task.size.cycles / (2 * 3e7) == pytest.approx(2.0)
    assert math.isclose(task.size.cycles, 1.2e8)


def test_expiry_tick_agrees_with_expired():
    for dt in (1.0, 0.1, 0.25, 0.3, 2.0):
        for deadline in (0.5, 1.0, 4.0, 99.9, 100.0):
            task = Task(1, "a", created=7, size=TaskSize(1, 1, 1, 1, deadline))
            t = task.expires_at(dt)
            assert task.expired(t, dt) and not task.expired(t - 1, dt), (dt, deadline)


def test_expiry_tick_is_exact_up_to_the_longest_deadline_and_never_past_it():
    # 2^50 ticks of 0.1 s: still exact, the first tick past the deadline
    longest = Task(1, "a", created=3, size=TaskSize(1, 1, 1, 1, LONGEST_DEADLINE_TICKS * 0.1))
    t = longest.expires_at(0.1)
    assert longest.expired(t, 0.1) and not longest.expired(t - 1, 0.1)
    # past it (1e300 s, or nan from a user's task source) consecutive ticks times dt round to the same
    # number, and the search used to loop for ever: now the task never expires within any run
    for deadline in (1e300, 2.0**60, math.nan):
        task = Task(1, "a", created=3, size=TaskSize(1, 1, 1, 1, deadline))
        assert task.expires_at(1.0) == 3 + LONGEST_DEADLINE_TICKS
        assert not task.expired(10**6, 1.0)


def test_noise_follows_the_bandwidth(tmp_path):
    from orchestrator.scenario import load_scenario
    from tests.conftest import write_scenario

    def rate(bandwidth):
        sc = load_scenario(write_scenario(tmp_path, {
            "network": {"bandwidth_hz": bandwidth, "path_loss": {"exponent": 3.0}},
            "topology": {"nodes": [{"id": "a", "client": True, "position": [0, 0]},
                                   {"id": "b", "position": [100, 0]}], "links": [["a", "b"]]}}))
        return sc.link[("a", "b")].rate_bps

    # SNR = 20 - (40 + 60) - (-174 + 10 log10 B) dB; at 2 MHz: 20 - 100 + 110.99 = 30.99 dB
    snr = 10 ** (30.99 / 10)
    assert rate(2e6) == pytest.approx(2e6 * math.log2(1 + snr), rel=1e-3)
    snr = 10 ** (20.99 / 10)  # ten times the bandwidth, ten times the noise
    assert rate(2e7) == pytest.approx(2e7 * math.log2(1 + snr), rel=1e-3)


def test_a_task_that_would_expire_in_the_link_queue_is_never_sent():
    import numpy as np

    from node_runtime.model.radio import Radio

    radio = Radio({"b": (8e6, 0.0)}, dt=1.0)  # 1 MB/s
    radio.reset(np.random.default_rng(0))
    # 10 MB at tick 0: on air 0 -> 10, arrives at 10
    assert radio.send(0, "b", 80e6, latest_start=100.0) == (10, 10.0, [])
    # a task whose deadline passes at tick 5 would only start at 10: expired, and no airtime is used ...
    assert radio.send(1, "b", 8e6, latest_start=5.0) == "expired"
    # ... so the next message starts right after the first one
    assert radio.send(2, "b", 8e6, latest_start=100.0) == (11, 1.0, [])


def test_a_workers_drain_tick_and_the_work_its_neighbours_see_hand_computed():
    """tx2_0 of aot1 (no controller: what arrives is queued) serves B = 4e6 cycles a tick. Tasks of 2.5 B and 1 B
    arrive in tick 0: the CPU gives the first B, so 2.5 B are left, and the queue drains at (0 + 1) + 2.5 = 3.5.
    Tick 1 only works through it: the same drain tick, nothing to broadcast. In tick 2 the first finishes and the
    second gets half a tick: (2 + 1) + 0.5 = 3.5 again, now with one task. In tick 3 it finishes: empty, (3 + 1) + 0.
    A neighbour that heard tick 0's state sees (3.5 - (t + 1)) s of work left at the end of tick t: 1.5 s at tick 1."""
    from node_runtime.model.messages import Envelope, Kind, NodeState
    from node_runtime.model.role import Outbox
    from node_runtime.model.view import NodeView
    from node_runtime.model.worker import Worker
    from orchestrator.scenario import load_scenario

    sc = load_scenario("aot1")
    worker = Worker(sc.node["tx2_0"], sc)
    budget = worker.budget
    assert budget == 4e6
    tasks = [Task(i, "tx2_0", 0, TaskSize(cycles, 0.0, 0.0, 1.0, 100.0)) for i, cycles in ((1, 2.5 * budget),
                                                                                           (2, budget))]
    states = []
    for t in range(5):
        out = Outbox(worker.id)
        out.tick = t
        inbox = [Envelope(Kind.TASK, "client:x", worker.id, i + 1, -1, 0, task) for i, task in enumerate(tasks)]
        worker.tick(t, inbox if t == 0 else [], out)
        states += [(t, e.body) for e in out.broadcasts if e.kind == Kind.STATE]
    assert states == [(0, NodeState("tx2_0", 2, 2, 3.5)), (2, NodeState("tx2_0", 1, 1, 3.5)),
                      (3, NodeState("tx2_0", 0, 0, 4.0))]
    seen = NodeView("tx2_0", 2, 2, 20, 4e6, 1, 1e7, 1, True, 0.0, 3.5)
    assert [seen.work_s(t, 1.0) for t in range(4)] == [2.5, 1.5, 0.5, 0.0]
    assert seen.work_s(1, 0.5) == 0.75  # seconds: ticks of dt
