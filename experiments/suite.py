"""The scenario generator and its named suites: regimes drawn by seed from one documented distribution.

A regime is a scenario file: a topology (ring, grid, random geometric, bridged clusters, n-tier, or one
of the Ether AoT networks) with a device mix from the Ether hardware profiles (rpi3, tx2, nuc, server),
one or two task kinds, their deadlines, an arrival schedule (constant, ramp, zigzag swing, or a rate drawn
per client) and a radio bandwidth, its arrival rate set for a drawn load: the work arriving per second
over the network's capacity (``orchestrator.scenario.costs.load_ratio``), up to 1.5, so that overloaded
regimes, where a policy chooses which tasks to lose, are in every suite. docs/benchmark.md gives the
distribution in full.

A suite's regime k is drawn from seed k of its split's regime seeds (``experiments.protocol.REGIMES``),
its family and load class taken in turn (``strata``): nothing is hand-picked, and the same seed writes
the same file, byte for byte.

    python -m experiments.suite                                   # train (100), validation (10), test (20)
    python -m experiments.suite --suites test --count 5 --out runs/suites-small
    python -m experiments.suite --suites validation --cards --episodes 2 --max-steps 100

Outputs under ``--out`` (default runs/suites): ``<split>/<regime>.yaml`` (``orchestrator validate`` takes
each), ``<split>/manifest.csv`` (one row per regime: seed, family, nodes, load ratio, ...) and, with
``--cards``, ``<split>/cards/``: the regime cards of ``experiments.regimes`` (every baseline, on the
split's own episode seeds) with their CSV files.
"""

from __future__ import annotations

import csv
import math
import statistics
from collections import Counter
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from agents.training import progress_bar, write_csv
from experiments import regimes
from experiments.common import Parser, positive_int
from experiments.protocol import EPISODES, REGIMES, SPLITS, Split
from orchestrator.scenario import ScenarioError, load_scenario
from orchestrator.scenario.costs import load_ratio


@dataclass(frozen=True)
class TaskKind:
    """A kind of task a regime may mix: its size and its deadline range U[low, high) seconds."""

    name: str
    instructions: float
    input_bytes: float
    output_bytes: float
    deadline: tuple[float, float]


@dataclass(frozen=True)
class Distribution:
    """What a regime is drawn from (docs/benchmark.md, "The distribution of regimes")."""

    families: tuple[str, ...] = ("ring", "grid", "random_geometric", "bridged_clusters", "n_tier", "ether")
    ether: tuple[str, ...] = ("ether/one_cluste_8rpi_manual.json", "ether/sbc_rpi3/network_1_clusters_3_type.json",
                              "ether/network_2_clusters.json")
    devices: tuple[tuple[str, float], ...] = (("tx2", 0.4), ("nuc", 0.4), ("server", 0.2))  # beside the rpi3s
    source_share: tuple[float, float] = (0.5, 0.8)  # share of rpi3 nodes (the task sources) in a generated topology
    kinds: tuple[TaskKind, ...] = (
        TaskKind("light", 2e7, 5e5, 5e4, (10, 30)),  # 5 s on an rpi3, 0.2 s on the server
        TaskKind("inference", 8e7, 2e6, 2e5, (20, 60)),  # 20 s on an rpi3, 2.5 s on a nuc
        TaskKind("heavy", 2e8, 2e6, 2e5, (40, 80)),  # aot3_compute's: 50 s on an rpi3, 2.3 s on the server
        TaskKind("bulk", 8e7, 2e7, 2e7, (60, 120)),  # the paper's compute with 20 MB each way
    )
    deadline_scale: tuple[float, float] = (0.75, 1.5)
    fixed_deadline: float = 0.3  # probability that a kind's deadline is fixed (its scaled low end) rather than drawn
    arrivals: tuple[str, ...] = ("constant", "linear", "zigzag", "uniform")
    swing: tuple[float, float] = (0.5, 1.0)  # a ramp, zigzag or uniform range spans mean x (1 -/+ swing)
    period_s: tuple[float, float] = (60.0, 240.0)  # of a zigzag
    loads: tuple[tuple[float, float], ...] = ((0.3, 0.7), (0.7, 1.0), (1.0, 1.5))  # work arriving over capacity,
    # one range per load class (light, busy, overloaded)
    peak_rate: float = 0.8  # tasks/s per source at most (a binary controller places one task a tick); a load
    # that needs more has its tasks' instructions scaled up instead
    bandwidth_hz: tuple[float, ...] = (0.5e6, 1e6, 2e6, 5e6)
    spacing_m: tuple[float, float] = (10.0, 60.0)


DISTRIBUTION = Distribution()
SUITES: dict[Split, int] = {"train": 100, "validation": 10, "test": 20}  # regimes per suite by default
STEPS = 400  # steps of a regime's episode
LOAD_CLASSES = ((0.7, "light"), (1.0, "busy"), (math.inf, "overloaded"))


def load_class(ratio: float) -> str:
    """light below 0.7, busy up to 1.0, overloaded above: more work arrives than the whole network serves."""
    return next(name for top, name in LOAD_CLASSES if ratio <= top)


@dataclass(frozen=True)
class Regime:
    name: str
    split: Split
    seed: int
    scenario: dict[str, Any]  # the file's content
    about: dict[str, Any]  # its manifest row

    def text(self) -> str:
        head = (f"# {self.name}: drawn by python -m experiments.suite from regime seed {self.seed} ({self.split} "
                f"set).\n# Generated: do not edit; docs/benchmark.md describes the distribution.\n")
        return head + yaml.safe_dump(self.scenario, sort_keys=False, default_flow_style=None, width=120)


def _round(x: float, digits: int = 4) -> float:
    return float(f"{x:.{digits}g}")


def _topology(rng: np.random.Generator, family: str, d: Distribution) -> tuple[dict[str, Any], str]:
    """The file's ``topology`` and a short description."""
    if family == "ether":
        path = d.ether[int(rng.integers(len(d.ether)))]
        return {"ether": path}, Path(path).stem
    spacing = _round(rng.uniform(*d.spacing_m), 3)
    if family == "n_tier":
        tiers = [int(rng.integers(3, 7)), int(rng.integers(1, 3)), 1]
        return ({"generator": {"kind": "n_tier", "tiers": tiers, "profiles": ["rpi3", "nuc", "server"],
                               "spacing": spacing, "tier_distance": _round(2 * spacing, 3)}},
                f"n_tier {'-'.join(map(str, tiers))}")
    if family == "ring":
        n = int(rng.integers(4, 11))
        gen, about = {"kind": "ring", "n": n, "spacing": spacing}, f"ring {n}"
    elif family == "grid":
        rows, cols = int(rng.integers(2, 4)), int(rng.integers(2, 5))
        n, about = rows * cols, f"grid {rows}x{cols}"
        gen = {"kind": "grid", "rows": rows, "cols": cols, "spacing": spacing}
    elif family == "random_geometric":
        n, size = int(rng.integers(5, 13)), _round(spacing * 4, 3)
        gen = {"kind": "random_geometric", "n": n, "radius": _round(size / 2, 3), "size": size,
               "seed": int(rng.integers(1_000_000))}
        about = f"random_geometric {n}"
    else:
        clusters, size = int(rng.integers(2, 4)), int(rng.integers(3, 5))
        n = clusters * size
        gen = {"kind": "bridged_clusters", "clusters": clusters, "size": size, "spacing": spacing,
               "cluster_distance": _round(3 * spacing, 3)}
        about = f"bridged_clusters {clusters}x{size}"
    share = rng.uniform(*d.source_share)
    names, weights = zip(*d.devices, strict=True)
    profiles = ["rpi3" if i == 0 or rng.random() < share else str(rng.choice(names, p=weights)) for i in range(n)]
    nodes = [{"id": f"n{i}", "profile": p} for i, p in enumerate(profiles) if p != "rpi3"]
    return {"generator": {**gen, "profile": "rpi3"}, **({"nodes": nodes} if nodes else {})}, about


def _tasks(rng: np.random.Generator, d: Distribution) -> list[dict[str, Any]]:
    picked = sorted(rng.choice(len(d.kinds), size=int(rng.integers(1, 3)), replace=False).tolist())
    out = []
    for i in picked:
        kind = d.kinds[i]
        scale = rng.uniform(*d.deadline_scale)
        low, high = _round(kind.deadline[0] * scale, 3), _round(kind.deadline[1] * scale, 3)
        deadline: Any = low if rng.random() < d.fixed_deadline else {"low": low, "high": high}
        out.append({"name": kind.name, "weight": _round(rng.uniform(1, 3), 3), "instructions": kind.instructions,
                    "input_bytes": kind.input_bytes, "output_bytes": kind.output_bytes, "cpi": 1.0,
                    "deadline": deadline})
    return out


def _arrival(kind: str, mean: float, swing: float, period: float, rising: bool) -> dict[str, Any]:
    low, high = _round(mean * (1 - swing)), _round(mean * (1 + swing))
    if kind == "constant":
        return {"kind": "constant", "rate": _round(mean)}
    if kind == "linear":
        return {"kind": "linear", "start": low if rising else high, "end": high if rising else low}
    if kind == "zigzag":
        return {"kind": "zigzag", "low": low, "high": high, "period": period}
    return {"kind": "uniform", "low": low, "high": high}


def strata(index: int, d: Distribution = DISTRIBUTION) -> tuple[str, tuple[float, float]]:
    """The family and the load range of a suite's regime ``index``: every family in turn, and every load class
    once with each family within 3 x (number of families) regimes, so that a small suite covers them evenly."""
    n = len(d.families)
    return d.families[index % n], d.loads[(index // n + index) % len(d.loads)]


def draw(seed: int, split: Split, index: int, steps: int = STEPS, d: Distribution = DISTRIBUTION) -> Regime:
    """Regime ``index`` of a ``split`` suite, from its regime ``seed`` (its family and load range from
    ``strata``): a scenario file and its manifest row."""
    rng = np.random.default_rng(seed)
    family, load = strata(index, d)
    topology, shape = _topology(rng, family, d)
    tasks = _tasks(rng, d)
    arrival_kind = d.arrivals[int(rng.integers(len(d.arrivals)))]
    swing = 0.0 if arrival_kind == "constant" else _round(rng.uniform(*d.swing), 3)
    period, rising = _round(rng.uniform(*d.period_s), 3), bool(rng.random() < 0.5)
    target = _round(rng.uniform(*load), 3)
    bandwidth = float(d.bandwidth_hz[int(rng.integers(len(d.bandwidth_hz)))])
    name = f"{split}-{index:03d}-{family}"
    scenario: dict[str, Any] = {
        "name": name,
        "description": f"{shape}; {', '.join(t['name'] for t in tasks)}; {arrival_kind} arrivals; load {target:g}",
        "simulation": {"dt": 1.0, "steps": steps, "seed": 0, "mode": "binary", "decision_interval": 1,
                       "max_hops": 1, "policy": "local"},
        "network": {"bandwidth_hz": bandwidth, "tx_power_dbm": 20.0},
        "workload": {"arrival": {"kind": "constant", "rate": 1.0}, "tasks": tasks},
        "topology": topology,
    }
    for attempt in range(100):  # a random geometric placement may leave a node alone: the next placement
        try:
            unit = load_ratio(load_scenario(scenario, name_hint=name))  # linear in the mean rate
            break
        except ScenarioError:
            if family != "random_geometric" or attempt == 99:
                raise
            topology["generator"]["seed"] += 1
    mean = target / unit
    scale = 1.0
    if mean * (1 + swing) > d.peak_rate:  # the load needs more tasks than a controller places: larger ones instead
        scale = _round(mean * (1 + swing) / d.peak_rate, 3)
        mean = d.peak_rate / (1 + swing)
        for t in tasks:
            t["instructions"] = _round(t["instructions"] * scale)
    scenario["workload"]["arrival"] = _arrival(arrival_kind, mean, swing, period, rising)
    sc = load_scenario(scenario, name_hint=name)
    ratio = load_ratio(sc)
    sources = set(sc.clients)
    kinds = ", ".join(f"{t['name']}:{t['weight']:g}" for t in tasks)
    about = {
        "name": name, "split": split, "index": index, "seed": seed, "family": family, "topology": shape,
        "nodes": len(sc.nodes), "workers": sum(n.has("worker") for n in sc.nodes), "sources": len(sources),
        "devices": " ".join(f"{p}:{c}" for p, c in sorted(Counter(n.profile for n in sc.nodes).items())),
        "tasks": kinds, "task_scale": scale, "deadlines": "; ".join(_deadline(t["deadline"]) for t in tasks),
        "arrival": arrival_kind, "mean_rate": _round(sc.workload.arrival.mean),
        "peak_rate": _round(sc.workload.arrival.peak), "bandwidth_mhz": bandwidth / 1e6,
        "median_rate_mbps": _round(statistics.median(lk.rate_bps for lk in sc.links) / 1e6, 3),
        "load_ratio": _round(ratio, 3), "load_class": load_class(ratio), "steps": steps,
    }
    return Regime(name, split, seed, scenario, about)


def _deadline(value: Any) -> str:
    return f"{value:g} s" if not isinstance(value, dict) else f"U[{value['low']:g}, {value['high']:g}) s"


def suite(split: Split, count: int, steps: int = STEPS, d: Distribution = DISTRIBUTION) -> list[Regime]:
    """The first ``count`` regimes of a split: regime k from the split's regime seed k."""
    return [draw(seed, split, k, steps, d) for k, seed in enumerate(REGIMES[split].seeds(count))]


def write(regimes_: Sequence[Regime], folder: Path) -> list[Path]:
    """Each regime's file and the manifest; returns the files, in suite order."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for r in regimes_:
        path = folder / f"{r.name}.yaml"
        path.write_text(r.text())
        paths.append(path)
    with open(folder / "manifest.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(regimes_[0].about), lineterminator="\n")
        writer.writeheader()
        writer.writerows(r.about for r in regimes_)
    return paths


def family_of(regime: Regime, path: Path) -> regimes.Family:
    """A regime as ``experiments.regimes`` measures and cards a family: at its own arrival schedule."""
    a = regime.about
    about = (f"{a['topology']} ({a['devices']}); tasks {a['tasks']} with deadlines {a['deadlines']}; {a['arrival']} "
             f"arrivals, mean {a['mean_rate']:g} tasks/s per source; links {a['median_rate_mbps']:g} Mbit/s "
             f"(median); load {a['load_ratio']:g} ({a['load_class']}). Regime seed {regime.seed}.")
    return regimes.Family(regime.name, str(path), (None,), about)


@dataclass(frozen=True)
class SuiteRegime:
    """One regime of a suite folder, as its manifest lists it."""

    name: str
    path: Path  # or a bundled scenario's name (aot1 ...)
    split: Split | None  # None: a scenario of no suite
    seed: int | None


def read_suite(folder: Path, split: Split | None = None) -> list[SuiteRegime]:
    """The regimes of a folder written by ``experiments.suite``; with ``split``, every one must belong to it
    (its manifest's split and its regime seed): a ValueError names the first that does not."""
    manifest = folder / "manifest.csv"
    try:
        with open(manifest, newline="") as f:
            rows = list(csv.DictReader(f))
    except FileNotFoundError:
        raise ValueError(f"{manifest}: not found; write a suite with python -m experiments.suite first") from None
    regimes = []
    for row in rows:
        try:
            regime = SuiteRegime(row["name"], folder / f"{row['name']}.yaml", row["split"], int(row["seed"]))
        except (KeyError, ValueError):
            raise ValueError(f"{manifest}: a row without a name, split and integer seed: {row}") from None
        if regime.split not in SPLITS or regime.seed not in REGIMES[regime.split]:
            raise ValueError(f"{manifest}: {regime.name}: regime seed {regime.seed} is not of the {regime.split!r} "
                             "regime seeds (experiments.protocol.REGIMES)")
        if split is not None and regime.split != split:
            raise ValueError(f"{manifest}: {regime.name} is a {regime.split} regime (seed {regime.seed}); "
                             f"this takes {split} regimes only: the seed sets never mix")
        if not regime.path.is_file():
            raise ValueError(f"{regime.path}: not found (listed in {manifest})")
        regimes.append(regime)
    if not regimes:
        raise ValueError(f"{manifest}: no regimes")
    return regimes


def main(argv: Sequence[str] | None = None) -> None:
    p = Parser(prog="python -m experiments.suite", description=__doc__.splitlines()[0])
    p.add_argument("--suites", nargs="+", choices=SPLITS, default=list(SPLITS), metavar="SPLIT",
                   help="suites to draw: train, validation, test (default: all three)")
    p.add_argument("--count", type=positive_int, default=None,
                   help=f"regimes per suite (default: {', '.join(f'{k} {v}' for k, v in SUITES.items())})")
    p.add_argument("--steps", type=positive_int, default=STEPS, help=f"steps of a regime's episode (default {STEPS})")
    p.add_argument("--out", type=Path, default=Path("runs/suites"), help="output folder (default runs/suites)")
    p.add_argument("--cards", action="store_true", help="also measure every baseline on each regime: its card")
    p.add_argument("--episodes", type=positive_int, default=3, help="card episodes per baseline (default 3)")
    p.add_argument("--max-steps", type=positive_int, default=None,
                   help="card steps per episode (default: the regime's; shorter only to try the command)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    args = p.parse_args(argv)
    for split in args.suites:
        drawn = suite(split, args.count or SUITES[split], args.steps)
        folder = args.out / split
        paths = write(drawn, folder)
        classes = Counter(r.about["load_class"] for r in drawn)
        print(f"wrote {len(drawn)} {split} regimes to {folder} ({', '.join(f'{v} {k}' for k, v in classes.items())})")
        if not args.cards:
            continue
        cards = folder / "cards"
        cards.mkdir(exist_ok=True)
        progress = progress_bar() if args.progress else None
        texts = []
        with progress or nullcontext():
            for regime, path in zip(drawn, paths, strict=True):
                family = family_of(regime, path)
                rows = regimes.measure(family, args.episodes, args.max_steps, progress,
                                       seed=EPISODES[split].seeds(args.episodes)[0])
                write_csv(cards / f"{regime.name}.csv", rows)
                texts.append(regimes.card(family, rows))
        (cards / "README.md").write_text(
            f"# Regime cards: the {split} suite\n\nMade by `python -m experiments.suite --cards` on the {split} "
            f"set's episode seeds ({EPISODES[split].start}, ...); manifest.csv beside the scenario files describes "
            "each regime.\n\n" + "\n".join(texts))
        print(f"wrote {len(texts)} cards to {cards / 'README.md'}")


if __name__ == "__main__":
    main()
