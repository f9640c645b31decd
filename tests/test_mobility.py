"""Moving nodes: positions from the mobility models, links that follow them, breaks, and the scenario keys.

The rules (docs/model.md, "Moving nodes"): a node's position at tick k is its model's at k·dt; a link with a
moving end exists in tick k only while its ends are within ``range_m`` and carries bits at the Shannon–Hartley
rate of their distance at k; a transfer that meets a tick without its link is lost (``link_broken``) or, with
``on_break: retry``, sent again whole from the first tick the link is back.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from env.observations import NeighbourField
from node_runtime.model.array import refusal
from node_runtime.model.positions import Positions
from node_runtime.model.rng import MOBILITY, stream
from orchestrator.scenario import ScenarioError, load_scenario
from tests.conftest import ROOT, model_part, run_summary, write_scenario
from tests.golden import Case, _launch
from tests.launcher import TIMEOUT

AREA = [[0, 0], [100, 50]]
# log-distance loss 40 + 30 log10(d) dB: with this noise, 20 dBm at 20 m is an SNR of exactly 3 (4.77 dB), so
# log2(1 + 3) = 2 bit/s/Hz: 2 Mbit/s over 1 MHz
NOISE_DBM = 20.0 - (40.0 + 30.0 * math.log10(20.0)) - 10.0 * math.log10(3.0)
RADIO = {"bandwidth_hz": 1.0e6, "noise_dbm": NOISE_DBM, "range_m": 50}


def positions(tmp_path: Path, mobility: dict, position=(10.0, 20.0), dt: float = 1.0, seed: int = 0,
              extra: dict | None = None) -> Positions:
    """The positions of node m (moving) beside a still node a, in a scenario of these settings."""
    sc = load_scenario(write_scenario(tmp_path, {
        "simulation": {"dt": dt, "seed": seed},
        "network": {"range_m": 1000},
        "topology": {"nodes": [{"id": "a", "client": True},
                               {"id": "m", "position": list(position), "mobility": mobility, **(extra or {})}]},
    }))
    p = Positions(sc)
    p.reset(seed)
    return p


# ----- the models, against positions worked out by hand -----

def test_gauss_markov_one_step_by_hand(tmp_path):
    """alpha 0.5, mean speed 2 m/s, mean direction 90°, sigmas 1 m/s and 10°, dt 2 s, from (50, 10).

    Tick 1: the node moves s0·dt = 2 x 2 = 4 m along d0 = 90°: (50, 14). Then, with w = the two standard
    normals of its stream (speed first), s1 = 0.5·2 + 0.5·2 + √0.75·1·w_s and d1 = 90° + √0.75·10°·w_d.
    Tick 2: it moves max(s1, 0)·2 m along d1."""
    p = positions(tmp_path, {"model": "gauss_markov", "area": AREA, "alpha": 0.5, "speed": 2, "direction": 90,
                             "speed_sigma": 1, "direction_sigma": 10}, position=(50, 10), dt=2.0)
    assert p.at("m", 0) == (50, 10)
    x1, y1 = p.at("m", 1)
    assert (x1, y1) == pytest.approx((50, 14))
    w_speed, w_direction = stream(0, 1, MOBILITY).standard_normal(2)
    s1 = 2.0 + math.sqrt(0.75) * w_speed
    d1 = math.radians(90 + math.sqrt(0.75) * 10 * w_direction)
    assert p.at("m", 2) == pytest.approx((x1 + max(s1, 0) * 2 * math.cos(d1), y1 + max(s1, 0) * 2 * math.sin(d1)))


def walk(p: Positions, ticks: int) -> np.ndarray:
    """Node m's positions in ticks 0 .. ticks - 1, one row each (pytest.approx compares arrays of any shape)."""
    return np.array([p.at("m", k) for k in range(ticks)])


def test_gauss_markov_without_noise_and_its_reflection(tmp_path):
    """Sigmas 0, alpha 0.3, 10 m/s, mean direction 0 (east), from x = 85 in [0, 100]. Tick 1: 95, and
    d1 = 0.3·0 + 0.7·0 = 0. Tick 2: 105 folds back to 95 and the direction to π; d2 = 0.3·π + 0.7·0 = 0.3π.
    Tick 3: 95 + 10·cos(0.3π) = 100.88 folds back to 200 − 100.88, y = 5 + 10·sin(0.3π)."""
    p = positions(tmp_path, {"model": "gauss_markov", "area": AREA, "alpha": 0.3, "speed": 10}, position=(85, 5))
    third = (200 - (95 + 10 * math.cos(0.3 * math.pi)), 5 + 10 * math.sin(0.3 * math.pi))
    assert walk(p, 4) == pytest.approx(np.array([(85, 5), (95, 5), (95, 5), third]))


def test_a_trace_is_interpolated_by_hand(tmp_path):
    """Samples at 0 s (0, 0), 4 s (40, 20) and 10 s (40, 80), dt 2 s: tick 1 (2 s) is halfway along the first
    leg (20, 10); tick 3 (6 s) a third along the second (40, 40); before and after, the end samples."""
    (tmp_path / "moves.csv").write_text("t,node,x,y\n4,m,40,20\n0,m,0,0\n10,m,40,80\n0,other,5,5\n")
    p = positions(tmp_path, {"model": "trace", "file": "moves.csv"}, dt=2.0)
    assert walk(p, 7) == pytest.approx(
        np.array([(0, 0), (20, 10), (40, 20), (40, 40), (40, 60), (40, 80), (40, 80)]))


def test_a_sumo_fcd_file_through_sumolib(tmp_path):
    """A vehicle of FCD output is a trace: veh0 at 0 s (10, 5) and 2 s (14, 9); at 1 s it is at (12, 7)."""
    (tmp_path / "fcd.xml").write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<fcd-export>\n'
        '  <timestep time="0.00">\n    <vehicle id="veh0" x="10.00" y="5.00" angle="0" speed="0"/>\n'
        '  </timestep>\n  <timestep time="2.00">\n'
        '    <vehicle id="veh0" x="14.00" y="9.00" angle="0" speed="2"/>\n'
        '    <vehicle id="veh1" x="0.00" y="0.00" angle="0" speed="0"/>\n  </timestep>\n</fcd-export>\n')
    p = positions(tmp_path, {"model": "fcd", "file": "fcd.xml", "vehicle": "veh0"})
    assert walk(p, 4) == pytest.approx(np.array([(10, 5), (12, 7), (14, 9), (14, 9)]))


def test_random_waypoint_walks_its_legs_at_their_speeds_and_pauses(tmp_path):
    """Each leg draws the waypoint's x, y, then its speed, from the node's stream; the node walks straight to
    it at that speed (a tick may end one leg and start the pause), pauses 3 s, and draws the next leg."""
    p = positions(tmp_path, {"model": "random_waypoint", "area": AREA, "speed": [2, 6], "pause": 3},
                  position=(50, 25), seed=4)
    rng = stream(4, 1, MOBILITY)
    here, t, expected = np.array([50.0, 25.0]), 0.0, {}
    while t < 60:  # continuous time: where the node is at every whole second
        target = np.array([rng.uniform(0, 100), rng.uniform(0, 50)])
        speed = rng.uniform(2, 6)
        length = float(np.linalg.norm(target - here))
        arrive = t + length / speed
        for k in range(math.ceil(t), math.floor(arrive) + 1):
            expected[k] = here + (target - here) * (k - t) / (arrive - t)
        for k in range(math.floor(arrive) + 1, math.floor(arrive + 3) + 1):
            expected[k] = target
        here, t = target, arrive + 3
    for k in range(60):
        assert p.at("m", k) == pytest.approx(tuple(expected[k])), k
        assert 0 <= p.at("m", k)[0] <= 100 and 0 <= p.at("m", k)[1] <= 50


def test_walks_are_the_same_whatever_order_they_are_asked_in(tmp_path):
    walk = {"model": "random_waypoint", "area": AREA, "speed": [1, 3]}
    forward = positions(tmp_path, walk, seed=9)
    ahead = [forward.at("m", k) for k in range(50)]
    (tmp_path / "b").mkdir()
    jumping = positions(tmp_path / "b", walk, seed=9)
    assert jumping.at("m", 49) == ahead[49] and [jumping.at("m", k) for k in range(50)] == ahead
    jumping.reset(10)
    assert [jumping.at("m", k) for k in range(50)] != ahead  # another seed, another walk


# ----- the hand trace: a node that moves out of range mid-transfer -----

TASKS = "time,client,instructions,input_bytes,output_bytes,cpi,deadline\n" + "".join(
    f"{t},a,1e6,375000,125000,1,100\n" for t in (0, 0, 7, 12))
MOVES = "t,node,x,y\n0,m,20,0\n5,m,20,0\n6,m,80,0\n12,m,80,0\n13,m,20,0\n"


def hand_trace(tmp_path: Path, on_break: str = "drop") -> Path:
    (tmp_path / "tasks.csv").write_text(TASKS)
    (tmp_path / "moves.csv").write_text(MOVES)
    return write_scenario(tmp_path, {
        "simulation": {"dt": 1.0, "steps": 22, "policy": "round_robin"},
        "network": {**RADIO, "on_break": on_break},
        "workload": {"trace": "tasks.csv"},
        "topology": {"nodes": [
            {"id": "a", "frequency": 1.0e6, "buffer": 4, "controller": True, "client": True, "position": [0, 0]},
            {"id": "m", "frequency": 2.0e6, "buffer": 4, "mobility": {"model": "trace", "file": "moves.csv"}},
        ]},
    })


def check_drop(s: dict) -> None:
    """a (0, 0) decides by round robin over the targets its mask allows; m (a worker) stands 20 m away in ticks
    0-5, at 80 m (out of the 50 m range) in ticks 6-12 and back at 20 m from tick 13. At 20 m both directions
    run at 2 Mbit/s (SNR 3 over 1 MHz). A task is 1e6 cycles (1 s on a, 0.5 s on m), 3e6 bits in, 1e6 bits out.

    - task 1 (created 0): observed at 2, round robin's first target: local. Served at 4 -> client at 5: 5 s.
    - task 2 (created 0): observed at 3 (m in range: [local, m]), next target m. The decision reaches a at 5:
      on air from 5.0 at 2 Mbit/s, 2e6 bits in tick 5; in tick 6 m is out of range: the transfer breaks there
      and the task is lost, link_broken, counted in tick 5, when it was sent (as link_loss is).
    - task 3 (created 7): observed at 9, m out of range: the mask allows local only. Served at 11 -> 12: 5 s.
    - task 4 (created 12): observed at 14, m back in range: round robin's 4th choice, m. On air 16.0 -> 17.5,
      at m at 18, served there in 18 (0.5 s of m's tick), its result on air 18.0 -> 18.5 -> a's client at 19: 7 s.

    Radio energy at 20 dBm (0.1 W): a 1.5 s on air (the lost transfer is not charged, as a lost message never
    is), m 0.5 s. Compute κ·cycles·f²: a 1e-27 x 2e6 x 1e12, m 1e-27 x 1e6 x 4e12."""
    assert s["totals"]["generated"] == 4 and s["totals"]["completed"] == 3
    assert s["totals"]["dropped"] == {"queue_full": 0, "expired": 0, "node_failure": 0, "link_loss": 0,
                                      "link_broken": 1, "total": 1}
    assert s["totals"]["offloaded"] == 2
    assert s["response_time"]["mean"] == pytest.approx(17.0 / 3) and s["response_time"]["max"] == 7.0
    assert s["nodes"]["a"]["energy_j"] == pytest.approx(0.15 + 1e-27 * 2e6 * 1e12)
    assert s["nodes"]["m"]["energy_j"] == pytest.approx(0.05 + 1e-27 * 1e6 * 4e12)


def check_retry(s: dict) -> None:
    """The same with ``on_break: retry``: task 2's transfer breaks in tick 6 and waits for its link, which is
    back in tick 13 (its deadline allows a start until tick 100): sent again whole, 13.0 -> 14.5, at m at 15,
    served in 15, its result on air 15.0 -> 15.5 -> a's client at 16: 16 s. Task 4 finds the link free at 16
    and goes as before (7 s). a's radio was on for 1 + 1.5 s (task 2, twice) and 1.5 s (task 4); m's, 0.5 s
    twice."""
    assert s["totals"]["generated"] == s["totals"]["completed"] == 4
    assert s["totals"]["dropped"]["total"] == 0 and s["totals"]["offloaded"] == 2
    assert s["response_time"]["mean"] == pytest.approx((5 + 16 + 5 + 7) / 4) and s["response_time"]["max"] == 16.0
    assert s["nodes"]["a"]["energy_j"] == pytest.approx(0.4 + 1e-27 * 2e6 * 1e12)
    assert s["nodes"]["m"]["energy_j"] == pytest.approx(0.1 + 1e-27 * 2e6 * 4e12)


def test_the_rates_of_the_hand_trace(tmp_path):
    sc = load_scenario(hand_trace(tmp_path))
    p = Positions(sc)
    p.reset(0)
    assert [p.rate("a", "m", k) for k in (0, 5)] == pytest.approx([2.0e6, 2.0e6])
    assert [p.rate("m", "a", k) for k in (6, 12)] == [0.0, 0.0]
    assert p.rate("m", "a", 13) == pytest.approx(2.0e6)


def test_hand_trace_a_transfer_breaks_when_its_node_leaves(tmp_path):
    out = tmp_path / "out"
    check_drop(run_summary(load_scenario(hand_trace(tmp_path)), ticks=22, out=out))
    rows = (out / "ticks.csv").read_text().splitlines()
    column = rows[0].split(",").index("dropped_link_broken")
    assert [int(r.split(",")[column]) for r in rows[1:]] == [0] * 5 + [1] + [0] * 16  # the drop: tick 5


def test_hand_trace_a_broken_transfer_is_retried_when_its_node_is_back(tmp_path):
    check_retry(run_summary(load_scenario(hand_trace(tmp_path, "retry")), ticks=22))


@pytest.mark.zenoh
@pytest.mark.parametrize("on_break", ["drop", "retry"])
def test_hand_trace_over_zenoh_in_every_layout(tmp_path, on_break):
    scenario = load_scenario(hand_trace(tmp_path, on_break))
    inproc = run_summary(scenario, ticks=22)
    for layout in ("per-role", "per-node"):
        over = run_summary(scenario, ticks=22, transport="zenoh", layout=layout)
        (check_drop if on_break == "drop" else check_retry)(over)
        assert model_part(over) == model_part(inproc)


# ----- determinism, neighbours, the example -----

def test_the_example_is_the_same_in_every_layout():
    """Fingerprints (summary and both tables) of the example: in process, and over Zenoh per node."""
    scenario = load_scenario(ROOT / "topologies" / "examples" / "mobile.yaml")
    ref = _launch(Case("mobile", 200, seed=3, layout="single"), scenario, "inproc")
    assert ref["totals"]["generated"] > 50
    for layout in ("per-role", "groups:3"):
        assert _launch(Case("mobile", 200, seed=3, layout=layout), scenario, "inproc") == ref, layout


@pytest.mark.zenoh
def test_the_example_is_the_same_over_zenoh():
    scenario = load_scenario(ROOT / "topologies" / "examples" / "mobile.yaml")
    ref = _launch(Case("mobile", 150, seed=5, layout="single"), scenario, "inproc")
    assert _launch(Case("mobile", 150, seed=5, layout="per-node"), scenario, "zenoh") == ref


def test_masks_and_rates_follow_the_neighbours_in_range(tmp_path):
    """The action space keeps every node that can ever come in range; the mask and the rate follow the tick."""
    from env import ZenohEdgeEnv

    env = ZenohEdgeEnv(load_scenario(hand_trace(tmp_path)), transport="inproc", max_steps=22)
    try:
        obs, _ = env.reset(seed=0)
        (agent,) = env.agents
        assert env.action_space(agent).n == 2
        seen = {}
        for tick in range(1, 16):
            obs, *_ = env.step({agent: 0})
            o = obs[agent]
            m = o["neighbours"][0]
            seen[tick] = (bool(o["task"][0]), int(o["action_mask"][1]), float(m[NeighbourField.RATE_MBPS]),
                          int(m[NeighbourField.AGE_TICKS]))
    finally:
        env.close()
    # tasks to place at 2, 3 and 14 (m in range: allowed) and 9 (out of range: masked); the rate is 0 in ticks
    # 6-12, and m's state, unheard while it is away, ages until its broadcast of 13 arrives at 14
    assert {t: v[1] for t, v in seen.items() if v[0]} == {2: 1, 3: 1, 9: 0, 14: 1}
    assert [round(v[2], 6) for v in seen.values()] == [2.0] * 5 + [0.0] * 7 + [2.0] * 3
    assert [v[3] for v in seen.values()] == [1] * 6 + [2, 3, 4, 5, 6, 7, 8] + [1, 1]


def test_a_scenario_without_mobility_keeps_its_hash_and_the_array_backend_refuses_a_moving_one(tmp_path):
    sc = load_scenario(ROOT / "topologies" / "examples" / "mobile.yaml")
    assert refusal(sc, "greedy").startswith(
        "scenario mobile: the array backend does not support moving nodes (car0, car1")
    assert sc.neighbours["s0"] and "car0" in sc.neighbours["s0"]
    plain = load_scenario(ROOT / "topologies" / "examples" / "minimal.yaml")
    assert plain.radio is None and "radio" not in plain.to_dict()["nodes"][0]


# ----- bad input -----

NODES = [{"id": "a", "client": True, "position": [10, 10]}]


@pytest.mark.parametrize(("mobility", "network", "message"), [
    ({"model": "teleport"}, {"range_m": 50},
     "topology.nodes[1].mobility.model: expected a model among 'random_waypoint', 'gauss_markov', 'trace', "
     "'fcd' (got 'teleport')"),
    ({"model": "random_waypoint", "area": AREA, "speed": [1, 2]}, {},
     "network.range_m: node 'm' moves: expected the radio range of moving nodes' links, in metres"),
    (None, {"range_m": 50}, "network.range_m: no node moves: give a node or profile a 'mobility'"),
    ({"model": "random_waypoint", "area": AREA, "speed": [3, 2]}, {"range_m": 50},
     "topology.nodes[1].mobility: speed: expected [low, high] with low <= high"),
    ({"model": "random_waypoint", "area": [[0, 0], [0, 50]], "speed": [1, 2]}, {"range_m": 50},
     "topology.nodes[1].mobility.area: expected [[x0, y0], [x1, y1]] with x0 < x1 and y0 < y1"),
    ({"model": "random_waypoint", "area": AREA, "speed": [1, 2], "paws": 1}, {"range_m": 50},
     "topology.nodes[1].mobility.paws: unknown key (did you mean 'pause'?)"),
    ({"model": "gauss_markov", "area": AREA, "alpha": 1.5, "speed": 1}, {"range_m": 50},
     "topology.nodes[1].mobility.alpha: expected a number <= 1 (got 1.5)"),
    ({"model": "gauss_markov", "area": [[200, 0], [300, 50]], "alpha": 0.5, "speed": 1}, {"range_m": 50},
     "topology.nodes[1].mobility.area: node 'm' starts at (10.0, 10.0), outside the area"),
    ({"model": "trace", "file": "none.csv"}, {"range_m": 50}, "topology.nodes[1].mobility.file: file not found"),
    ({"model": "trace", "file": "moves.csv", "node": "x"}, {"range_m": 50},
     "topology.nodes[1].mobility.file: {path}/moves.csv has no node 'x' (node 'm')"),
    ({"model": "trace", "file": "bad.csv"}, {"range_m": 50},
     "topology.nodes[1].mobility.file: {path}/bad.csv:3: expected numbers t, x and y and a node id"),
    ({"model": "fcd", "file": "moves.csv"}, {"range_m": 50},
     "topology.nodes[1].mobility.file: {path}/moves.csv: not an XML"),
    ({"model": "trace", "file": "moves.csv"}, {"range_m": -1}, "network.range_m: expected a number > 0 (got -1)"),
    ({"model": "trace", "file": "moves.csv"}, {"range_m": 50, "on_break": "resend"},
     "network.on_break: expected 'drop' or 'retry' (got 'resend')"),
])
def test_bad_mobility_settings_name_the_key(tmp_path, mobility, network, message):
    (tmp_path / "moves.csv").write_text(MOVES)
    (tmp_path / "bad.csv").write_text("t,node,x,y\n0,m,1,1\n1,m,east,1\n")
    node = {"id": "m", "position": [10, 10], **({"mobility": mobility} if mobility else {})}
    path = write_scenario(tmp_path, {"network": network, "topology": {"nodes": [*NODES, node],
                                                                      "links": [] if mobility else [["a", "m"]]}})
    with pytest.raises(ScenarioError) as e:
        load_scenario(path)
    expected = message.format(path=tmp_path)
    assert any(expected in line for line in str(e.value).splitlines()), str(e.value)


def test_a_link_of_a_moving_node_cannot_be_listed(tmp_path):
    (tmp_path / "moves.csv").write_text(MOVES)
    path = write_scenario(tmp_path, {"network": {"range_m": 50}, "topology": {"nodes": [
        *NODES, {"id": "m", "mobility": {"model": "trace", "file": "moves.csv"}}], "links": [["a", "m"]]}})
    with pytest.raises(ScenarioError, match=r"topology.links\[0\].between: 'm' moves: its links follow its position"):
        load_scenario(path)


def test_validate_says_so_in_one_line_with_status_2(tmp_path):
    path = write_scenario(tmp_path, {"network": {"range_m": 50}, "topology": {"nodes": [
        *NODES, {"id": "m", "mobility": {"model": "gauss_markov", "area": AREA, "alpha": 2, "speed": 1}}]}})
    proc = subprocess.run([sys.executable, "-m", "orchestrator.cli", "validate", str(path)], cwd=ROOT,
                          capture_output=True, text=True, timeout=TIMEOUT)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"{path}: topology.nodes[1].mobility.alpha: expected a number <= 1 (got 2)"]


# ----- the topology's frames -----

def test_the_topology_draws_positions_over_time_as_a_strip_of_frames(tmp_path):
    from orchestrator.viewers.draw import draw_frames, frame_ticks

    sc = load_scenario(ROOT / "topologies" / "examples" / "mobile.yaml")
    assert frame_ticks(sc, 4) == [0, 199, 398, 597] and frame_ticks(sc, 3, every=400) == [0, 400, 599]
    png = draw_frames(sc, tmp_path / "f" / "frames.png", [0, 30, 60, 90])
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    run = [sys.executable, "-m", "orchestrator.cli", "topology"]
    strip = ["examples/mobile", "--frames", "2", "--every", "10", "--png", str(tmp_path / "cli.png")]
    proc = subprocess.run([*run, *strip], cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)
    assert proc.returncode == 0 and (tmp_path / "cli.png").stat().st_size > 10_000, proc.stderr
    proc = subprocess.run([*run, "examples/minimal", "--frames", "2", "--png", str(tmp_path / "x.png")], cwd=ROOT,
                          capture_output=True, text=True, timeout=TIMEOUT)
    assert proc.returncode == 2
    assert proc.stderr.strip() == "orchestrator topology: --frames: no node of minimal moves (frames show moving nodes)"


# ----- a moving link, tick by tick -----

def carry(rates: dict[int, float], bits: float, retry: bool = False, latest: float = math.inf, horizon: int = 99,
          tick: int = 0, link=None):
    from node_runtime.model.radio import MovingLink

    link = link or MovingLink(lambda k: rates.get(k, 0.0), 1.0, retry, horizon)
    return link, link.carry(tick, bits, latest)


def test_a_transfer_advances_at_each_ticks_rate():
    """1, 2, then 4 Mbit/s in ticks 0, 1, 2: 3.5e6 bits carry 1e6 in tick 0, 2e6 in tick 1 and the last 0.5e6
    in an eighth of tick 2: finish 2.125, arrival 3, 2.125 s on air. The next message waits until 2.125."""
    link, sent = carry({0: 1e6, 1: 2e6, 2: 4e6, 3: 4e6}, 3.5e6)
    assert sent == (3, pytest.approx(2.125), []) and link.busy_until == pytest.approx(2.125)
    assert link.carry(2, 1.5e6, math.inf) == (3, pytest.approx(0.375), [])  # 2.125 + 0.375 = 2.5 -> at 3


def test_a_transfer_that_meets_a_broken_link_is_lost_or_sent_again_whole():
    """2 Mbit/s in ticks 0 and 4 on, no link in 1-3. 3e6 bits from 0: 2e6 in tick 0, then the break at 1.
    Dropped: lost, the link free from 1. Retried: again whole from 4 (4.0 -> 5.5, arrival 6, 1 + 1.5 s on air),
    unless its deadline (latest start 3) or the episode's end (horizon 3) comes first."""
    rates = {0: 2e6, 4: 2e6, 5: 2e6, 6: 2e6}
    link, sent = carry(rates, 3e6)
    assert sent == "link_broken" and link.busy_until == 1.0
    link, sent = carry(rates, 3e6, retry=True)
    assert sent == (6, pytest.approx(2.5), []) and link.busy_until == pytest.approx(5.5)
    assert carry(rates, 3e6, retry=True, latest=3.0)[1] == "link_broken"
    assert carry(rates, 3e6, retry=True, horizon=3)[1] == "link_broken"
    assert carry(rates, 1e6, tick=2)[1] == "link_broken"  # no link when it would start
