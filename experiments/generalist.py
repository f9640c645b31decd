"""The generalist: one policy trained across the training suite, evaluated zero-shot on the test suite.

Every training episode draws a regime from the training suite and an episode seed from the training
episode seeds; one PPO network with shared parameters acts for every agent of every regime. It sees a
regime only through its observations: every agent has ``neighbour_slots`` slots whatever its degree (the
absent ones masked), its features are the scale-free ones of ``agents.common.flatten``, and no agent id
is appended (``agent_id=false``: the number of agents differs between regimes). By default 25 episodes run at
once on the array backend, 5 regimes a round (``agents.vector_ppo``). Checkpoints are scored on the
validation suite, for model selection only (``best.pt``); the test suite is for ``evaluate``, once. The
defaults of ``train`` were chosen on the validation suite (``PRICE``, ``ENVS``, ``REGIMES``).

    python -m experiments.suite --out runs/suites
    python -m experiments.generalist train --suite runs/suites/train --validation runs/suites/validation \\
        --seed 0 --out runs/generalist/seed-0                        # 200 episodes, 25 at a time
    python -m experiments.generalist train --suite runs/suites/train --validation runs/suites/validation \\
        --envs 1 --seed 0 --out runs/generalist-serial/seed-0        # one episode at a time, on any backend
    python -m experiments.generalist specialist --suite runs/suites/test --episodes 100 --out runs/specialists
    python -m experiments.generalist evaluate runs/generalist/seed-*/best.pt --specialists runs/specialists \\
        --baselines local greedy --suite runs/suites/test --episodes 5 --csv runs/generalist/test.csv
    python -m experiments.generalist evaluate runs/generalist/seed-*/best.pt --baselines --batched \\
        --scenarios aot1 aot2 aot3 aot4 --episodes 5 --csv runs/generalist/aot.csv   # topologies it never saw

``evaluate`` writes one raw row (``experiments.raw``) per policy, training run, regime and episode, which
``python -m experiments.report`` reads beside the bound's. docs/benchmark.md, "The generalist".
"""

from __future__ import annotations

import argparse
import json
import math
import pickle
import shutil
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agents import BASELINES, PPO, AgentPolicy, Baseline, Learner, load_learner
from agents.common import AgentSpec
from agents.training import CsvWriter, progress_bar, run_episode, write_csv
from agents.vector_ppo import Regime, VectorPPO
from env import ZenohEdgeEnv
from env.reward import RewardSettings
from experiments import raw, tune_baselines
from experiments import train as train_command
from experiments.common import (
    EVAL_BACKEND,
    Parser,
    add_backend_argument,
    add_learner_arguments,
    choose_backend,
    congestion_price,
    learner_config,
    make_env,
    positive_int,
    set_threads,
)
from experiments.protocol import EPISODES, SPLITS
from experiments.suite import SuiteRegime, read_suite
from experiments.tune_baselines import CRITERION
from orchestrator.scenario import load_scenario
from orchestrator.scenario.errors import ScenarioError

SLOTS = 32  # neighbour slots: the largest degree is 18 in the first 100 train, 10 validation and 20 test regimes,
# 30 in the bundled AoT networks (aot4), which the generalist is evaluated on as topologies it never saw
REWARD = "marginal"  # experiments.train's for PPO: each decision learns from its own tasks' credit
MODES = ("sampled", "greedy")  # how a learner acts when evaluated
OPEN_ENVS = 8  # regimes whose simulation stays open between the episodes that draw them
# train's defaults, chosen on the validation suite (docs/benchmark.md, "Settings chosen on validation"):
PRICE = 0.5  # the marginal reward's congestion price, below the environment's default
ENVS, REGIMES = 25, 5  # episodes at a time on the array backend, and regimes drawn per round (5 copies each)


def scenarios(names: Sequence[str]) -> list[SuiteRegime]:
    """Scenarios of no suite (bundled names or files) to evaluate on, as regimes; a ValueError for a bad one."""
    out = []
    for name in names:
        try:
            load_scenario(name)
        except ScenarioError as e:
            raise ValueError(str(e).splitlines()[0]) from None
        out.append(SuiteRegime(Path(name).stem, Path(name), None, None))
    return out


def regime_env(regime: SuiteRegime, slots: int, max_steps: int | None, price: float | None = None,
               backend: str = "emulator") -> ZenohEdgeEnv:
    """A regime's environment with ``slots`` neighbour slots for every agent: the generalist's one shape."""
    return ZenohEdgeEnv(str(regime.path), backend=backend, transport="inproc", neighbour_slots=slots,
                        max_steps=max_steps, reward=REWARD, congestion_price=price)


def flat_env(regime: SuiteRegime, slots: int, max_steps: int | None, price: float | None) -> ZenohEdgeEnv:
    """``regime_env``'s settings with flat observations on the array backend: what ``VectorPPO`` steps."""
    return ZenohEdgeEnv(str(regime.path), backend="array", transport="inproc", observation="flat", info_numbers=False,
                        neighbour_slots=slots, max_steps=max_steps, reward=REWARD, congestion_price=price)


def regime_backends(prog: str, regimes: Sequence[SuiteRegime], backend: str) -> dict[str, str]:
    """Each regime's backend by name (``--backend auto``: one line on stderr says which and why)."""
    chosen = choose_backend(prog, [(str(r.path), None) for r in regimes], backend)
    return {r.name: chosen[str(r.path), None] for r in regimes}


class OpenEnvs:
    """The environments of the regimes drawn last, kept open (starting one costs more than an episode's reset);
    ``make`` opens a regime's (default: ``regime_env``'s environment on the regime's backend)."""

    def __init__(self, slots: int, max_steps: int | None, price: float | None, backends: dict[str, str],
                 keep: int = OPEN_ENVS, make: Callable[[SuiteRegime], Any] | None = None) -> None:
        self.slots, self.max_steps, self.price, self.backends, self.keep = slots, max_steps, price, backends, keep
        self.make = make or (lambda r: regime_env(r, self.slots, self.max_steps, self.price, self.backends[r.name]))
        self.open: OrderedDict[str, Any] = OrderedDict()

    def get(self, regime: SuiteRegime) -> Any:
        env = self.open.pop(regime.name, None)
        if env is None:
            env = self.make(regime)
        self.open[regime.name] = env
        while len(self.open) > self.keep:
            self.open.popitem(last=False)[1].close()
        return env

    def close(self) -> None:
        for env in self.open.values():
            env.close()
        self.open.clear()


def check_degrees(regimes: Sequence[SuiteRegime], slots: int) -> None:
    """Every regime's largest degree fits ``slots``: checked before a long run starts, not when it draws one."""
    for regime in regimes:
        try:
            sc = load_scenario(str(regime.path))
        except ScenarioError as e:
            raise ValueError(str(e).splitlines()[0]) from None
        largest = max((len(sc.neighbours[n]) for n in sc.controllers), default=0)
        if largest > slots:
            raise ValueError(f"{regime.path}: an agent has {largest} neighbours, more than --slots {slots}")


def generalist(slots: int, config: Any, device: str = "cpu") -> PPO:
    """A PPO learner for any agent of any regime of up to ``slots`` neighbours."""
    return PPO({"agent": AgentSpec(slots=slots, n_actions=1 + slots)}, config, device)


CURVES = ("return", CRITERION, "penalised_response_time")  # each checkpoint's validation means: learning curves


def validate(policy: Learner, regimes: Sequence[SuiteRegime], envs: OpenEnvs | list[Regime], episodes: int,
             greedy: bool, progress: Any = None) -> dict[str, float]:
    """Means over the validation regimes, on the validation episode seeds, of ``CURVES``: ``CRITERION``
    (completion ratio) chooses the checkpoint, the others are logged for the learning curves. The policy acts
    as it will be evaluated: its most likely action (``greedy``) or a sample. ``envs``: the regimes' open
    environments, played one episode at a time, or their ``Regime``s of ``episodes`` copies each, played all at
    once (``VectorPPO.play``: the same episodes, action for action when greedy)."""
    values: dict[str, list[float]] = {m: [] for m in CURVES}
    if isinstance(envs, list):
        seeds = [EPISODES["validation"].seeds(episodes)] * len(envs)
        for rows in VectorPPO(policy).play(envs, seeds, greedy):
            for m in CURVES:
                values[m] += [row[m] for row in rows]
        return {m: float(np.nanmean(v)) for m, v in values.items()}
    task = progress.add_task("validate", total=len(regimes) * episodes, info="") if progress else None
    sampled, policy.config.sample_eval = policy.config.sample_eval, not greedy
    for regime in regimes:
        for seed in EPISODES["validation"].seeds(episodes):
            row = run_episode(envs.get(regime), policy, seed)
            for m in CURVES:
                values[m].append(row[m])
            if progress is not None:
                progress.update(task, advance=1)
    policy.config.sample_eval = sampled
    if progress is not None:
        progress.remove_task(task)
    return {m: float(np.nanmean(v)) for m, v in values.items()}


def train(args: argparse.Namespace, p: Parser) -> None:
    try:
        regimes = read_suite(args.suite, "train")
        checks = read_suite(args.validation, "validation") if args.validation else []
        config = learner_config("ppo", seed=args.seed, reward=REWARD, hidden=args.hidden,
                                base={"shared": True, "agent_id": False}, overrides=args.overrides)
        if config.centralised_critic or not config.shared or config.agent_id:
            raise ValueError("the generalist is one shared network without agent ids: leave shared, agent_id "
                             "and centralised_critic at their defaults")
        seeds = EPISODES["train"].seeds(args.episodes, offset=args.seed * args.episodes)
        check_degrees([*regimes, *checks], args.slots)
        if args.envs > 1 and (args.episodes % args.envs or args.checkpoint_every % args.envs):
            raise ValueError(f"--envs {args.envs} runs that many episodes at once: it must divide "
                             f"--episodes ({args.episodes}) and --checkpoint-every ({args.checkpoint_every})")
        args.regimes = args.regimes or (REGIMES if args.envs % REGIMES == 0 else 1)
        if args.envs % args.regimes:
            raise ValueError(f"--regimes {args.regimes} must divide --envs {args.envs} (each regime drawn in a round "
                             "runs as many of its episodes)")
    except ValueError as e:
        p.error(str(e))
    backends = regime_backends(p.prog, [*regimes, *checks], args.backend)
    if args.envs > 1 and (emulated := [r.name for r in regimes if backends[r.name] != "array"]):
        p.error(f"--envs {args.envs} trains on the array backend, which does not run {emulated[0]} "
                f"(--backend {args.backend}); train it with --envs 1")
    set_threads(args.threads)
    args.out.mkdir(parents=True, exist_ok=True)
    envs = OpenEnvs(args.slots, args.max_steps, args.congestion_price, backends)
    learner = generalist(args.slots, config, args.device)
    vectorised = (args.slots, args.max_steps, args.congestion_price)
    checked: OpenEnvs | list[Regime] = OpenEnvs(*vectorised, backends, keep=len(checks))
    if args.envs > 1 and all(backends[r.name] == "array" for r in checks):  # every validation episode at once
        checked = [Regime(learner, flat_env(r, *vectorised), args.validation_episodes) for r in checks]
    try:
        first = envs.get(regimes[0])  # every regime's shape is checked as it is drawn; this sizes the schedules
    except (ValueError, ScenarioError) as e:
        p.error(f"{regimes[0].path}: {str(e).splitlines()[0]}")
    (args.out / "config.json").write_text(json.dumps({
        "algo": "ppo", "suite": str(args.suite), "regimes": [r.name for r in regimes],
        "validation": str(args.validation) if args.validation else None, "episodes": args.episodes,
        "max_steps": first.max_steps, "slots": args.slots, "reward": REWARD, "backends": backends,
        "congestion_price": first.reward_settings.congestion_price, "envs": args.envs,
        "regimes_per_round": args.regimes, "validation_episodes": args.validation_episodes,
        "validation_mode": args.validation_mode, "config": asdict(config)},
        indent=1))
    learner.start_training(args.episodes * first.max_steps)
    draw = np.random.default_rng(args.seed)  # which regime each episode (each K episodes) runs: from the training seed
    log = CsvWriter(args.out / "train.csv")
    checks_log = CsvWriter(args.out / "validation.csv") if checks else None
    best, frames = -math.inf, 0
    copies = OpenEnvs(*vectorised, backends, keep=max(OPEN_ENVS, 2 * args.regimes),
                      make=lambda r: Regime(learner, flat_env(r, *vectorised), args.envs // args.regimes))
    trainer = VectorPPO(learner)
    progress = progress_bar() if args.progress else None
    with progress or nullcontext():
        bar = progress.add_task("train generalist", total=args.episodes, info="") if progress else None
        for k in range(0, args.episodes, args.envs):
            drawn = [regimes[int(draw.integers(len(regimes)))] for _ in range(args.regimes)]
            try:
                if args.envs == 1:
                    env = envs.get(drawn[0])
                    ran = [(drawn[0], env, [run_episode(env, learner, seeds[k], learner) | learner.stats()])]
                else:
                    groups = [copies.get(r) for r in drawn]
                    # a regime drawn twice in a round: its second draw gets copies of its own
                    groups = [copies.make(r) if any(h is g for h in groups[:i]) else g
                              for i, (r, g) in enumerate(zip(drawn, groups, strict=True))]
                    each = args.envs // args.regimes
                    out = trainer.episode(groups, [seeds[k + i * each:k + (i + 1) * each] for i in range(len(groups))])
                    ran = [(r, g.env, rows) for r, g, rows in zip(drawn, groups, out, strict=True)]
            except (ValueError, ScenarioError) as e:
                p.error(f"{drawn[0].path}: {str(e).splitlines()[0]}")
            episode = k
            for regime, env, rows in ran:
                for row in rows:
                    frames += row["steps"] * len(env.possible_agents)  # agent-steps, the learning curves' x axis
                    log.write({"episode": episode, "regime": regime.name, "episode_seed": row.pop("seed"),
                               "agents": len(env.possible_agents), "frames": frames, **row})
                    episode += 1
            done = k + args.envs
            if progress is not None:
                completion = np.mean([row["completion_ratio"] for _, _, rows in ran for row in rows])
                progress.update(bar, advance=args.envs, info=f"{drawn[0].name}  completion {completion:.2f}  "
                                                             f"{ran[0][2][0]['wall_s']:.1f} s/episode")
            if done % args.checkpoint_every == 0 or done == args.episodes:
                path = args.out / f"ckpt-{done:05d}.pt"
                learner.save(path)
                if checks_log is not None:
                    start = time.perf_counter()
                    means = validate(learner, checks, checked, args.validation_episodes,
                                     args.validation_mode == "greedy", progress)
                    checks_log.write({"episode": done, "frames": frames, "checkpoint": path.name, **means,
                                      "wall_s": time.perf_counter() - start})
                    if means[CRITERION] > best:
                        best = means[CRITERION]
                        shutil.copyfile(path, args.out / "best.pt")
    copies.close()
    log.close()
    if checks_log is not None:
        checks_log.close()
    envs.close()
    for opened in checked if isinstance(checked, list) else [checked]:
        opened.close()
    learner.save(args.out / "last.pt")
    chosen = f"best.pt (validation {CRITERION} {best:.3f})" if checks else "no validation suite: no best.pt"
    print(f"wrote {args.out / 'train.csv'}, checkpoints and last.pt; {chosen}")


def specialist(args: argparse.Namespace, p: Parser) -> None:
    """Per regime, ``experiments.train ppo`` on that regime alone (training episode seeds)."""
    try:
        regimes = read_suite(args.suite)
    except ValueError as e:
        p.error(str(e))
    for regime in regimes:
        argv = ["ppo", "--scenario", str(regime.path), "--episodes", str(args.episodes), "--seed", str(args.seed),
                "--out", str(args.out / regime.name), "--threads", str(args.threads), "--device", args.device]
        argv += [*(["--max-steps", str(args.max_steps)] if args.max_steps else []),
                 *(["--hidden", *map(str, args.hidden)] if args.hidden else []),
                 *(a for o in args.overrides for a in ("--set", o)),
                 *([] if args.progress else ["--no-progress"]),
                 "--backend", args.backend, "--reward", REWARD, "--price", str(args.congestion_price),
                 "--envs", str(args.envs)]
        train_command.main(argv)


@dataclass(frozen=True)
class Entry:
    """A policy to evaluate: a baseline, the generalist's checkpoint, or a directory of specialists."""

    label: str
    baseline: type[Baseline] | None = None
    checkpoint: Path | None = None
    specialists: Path | None = None

    def policy(self, regime: SuiteRegime, device: str) -> AgentPolicy:
        if self.baseline is not None:
            return self.baseline(0)
        path = self.checkpoint or self.specialists / regime.name / "ppo.pt"
        return load_learner(path, device)

    def env(self, policy: AgentPolicy, regime: SuiteRegime, max_steps: int | None, price: float,
            backend: str) -> ZenohEdgeEnv:
        if self.checkpoint is not None:
            return regime_env(regime, policy.specs["agent"].slots, max_steps, price, backend)
        return make_env(str(regime.path), None, max_steps, REWARD, congestion_price=price, backend=backend)


def entries(args: argparse.Namespace) -> list[Entry]:
    """What ``evaluate`` runs, checked before any episode: a ValueError names what is wrong."""
    out = []
    for path in args.checkpoints:
        try:
            learner = load_learner(path, "cpu")
        except (OSError, RuntimeError, ValueError, KeyError, pickle.UnpicklingError) as e:
            why = str(e).splitlines()[0]
            raise ValueError(f"{path}: not a checkpoint of this project's learners ({why})") from None
        if learner.config.agent_id or list(learner.specs) != ["agent"]:
            raise ValueError(f"{path}: not a generalist's checkpoint (python -m experiments.generalist train); "
                             "evaluate a per-regime checkpoint with --specialists")
        out.append(Entry("generalist", checkpoint=path))
    names = list(BASELINES) if args.baselines == [] else args.baselines or []
    for name in names:
        if name not in BASELINES:
            raise ValueError(f"--baselines {name}: not a baseline ({', '.join(BASELINES)})")
        out.append(Entry(name, baseline=BASELINES[name]))
    if args.tuned is not None:
        try:
            tuned = tune_baselines.chosen(args.tuned)
        except (OSError, ValueError, KeyError) as e:
            raise ValueError(f"--tuned {args.tuned}: not a chosen.json of experiments.tune_baselines ({e})") from None
        out += [Entry(f"{name}_tuned", baseline=cls) for name, cls in tuned.items()]
    if args.specialists is not None:
        out.append(Entry("specialist", specialists=args.specialists))
    if not out:
        raise ValueError("nothing to evaluate: give checkpoints, --baselines, --tuned or --specialists")
    return out


def evaluate(args: argparse.Namespace, p: Parser) -> None:
    try:
        regimes = [*(read_suite(args.suite) if args.suite else []), *scenarios(args.scenarios)]
        if not regimes:
            raise ValueError("nothing to evaluate on: give --suite, --scenarios or both")
        split = args.split or regimes[0].split or "test"
        seeds = EPISODES[split].seeds(args.episodes)
        todo = entries(args)
        for entry in todo:
            if entry.checkpoint is not None:
                check_degrees(regimes, load_learner(entry.checkpoint).specs["agent"].slots)
        for regime in regimes:
            missing = args.specialists / regime.name / "ppo.pt" if args.specialists else None
            if missing is not None and not missing.is_file():
                how = (f"python -m experiments.generalist specialist --suite {args.suite} --out {args.specialists}"
                       if regime.split else f"python -m experiments.train ppo --scenario {regime.path} --out "
                                            f"{args.specialists / regime.name}")
                raise ValueError(f"{missing}: no specialist for {regime.name} ({how})")
    except ValueError as e:
        p.error(str(e))
    backends = regime_backends(p.prog, regimes, args.backend)
    if args.batched and (emulated := [r.name for r in regimes if backends[r.name] != "array"]):
        p.error(f"--batched plays on the array backend, which does not run {emulated[0]} (--backend {args.backend}); "
                "evaluate it without --batched")
    set_threads(1)
    rows: list[dict[str, Any]] = []
    progress = progress_bar() if args.progress else None
    with progress or nullcontext():
        runs = sum(len(args.modes) if e.baseline is None else 1 for e in todo) * len(regimes) * len(seeds)
        bar = progress.add_task("evaluate", total=runs, info="") if progress else None
        for entry in todo:
            if args.batched and entry.checkpoint is not None:
                try:
                    rows += batched(entry, regimes, seeds, args)
                except (ValueError, ScenarioError) as e:
                    p.error(f"{entry.checkpoint}: {str(e).splitlines()[0]}")
                if progress is not None:
                    progress.update(bar, advance=len(args.modes) * len(regimes) * len(seeds), info=entry.label)
                continue
            for regime in regimes:
                policy = entry.policy(regime, args.device)
                try:
                    env = entry.env(policy, regime, args.max_steps, args.congestion_price, backends[regime.name])
                except (ValueError, ScenarioError) as e:
                    p.error(f"{regime.path}: {str(e).splitlines()[0]}")
                for mode in args.modes if isinstance(policy, Learner) else [None]:
                    label = entry.label
                    if mode is not None:  # a learner: its sampled policy, or its most likely action
                        policy.config.sample_eval = mode == "sampled"
                        label = labelled(label, mode)
                    trained = policy.config.seed if isinstance(policy, Learner) else None
                    start = time.perf_counter()
                    for k, seed in enumerate(seeds):
                        episode = {"episode": k, **run_episode(env, policy, seed)}
                        rows.append(raw.row(label, trained, regime.path, regime.name, episode,
                                            {"backend": backends[regime.name]}))
                        if progress is not None:
                            progress.update(bar, advance=1, info=f"{label} {regime.name}")
                    if progress is None:
                        print(f"{label} on {regime.name}: {len(seeds)} episodes in {time.perf_counter() - start:.1f} s")
                env.close()
    write_csv(args.csv, rows)
    print(f"wrote {len(rows)} rows to {args.csv} ({split} episodes {seeds[0]}..{seeds[-1]}; learners: "
          f"{', '.join(args.modes)})")


def labelled(policy: str, mode: str) -> str:
    """A learner's policy label in a mode: ``_greedy`` appended to its most likely action's."""
    return policy if mode == "sampled" else f"{policy}_greedy"


def batched(entry: Entry, regimes: Sequence[SuiteRegime], seeds: Sequence[int], args: argparse.Namespace
            ) -> list[dict[str, Any]]:
    """``evaluate``'s rows of a generalist checkpoint with every episode of every regime played at once, copies on
    the array backend (``VectorPPO.play``); regimes of one episode length step together."""
    policy = load_learner(entry.checkpoint, args.device)
    slots = policy.specs["agent"].slots
    groups: dict[int, list[tuple[SuiteRegime, Regime]]] = {}
    for regime in regimes:
        played = Regime(policy, flat_env(regime, slots, args.max_steps, args.congestion_price), len(seeds))
        groups.setdefault(played.env.max_steps, []).append((regime, played))
    out: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for mode in args.modes:
        label = labelled(entry.label, mode)
        for group in groups.values():
            played = VectorPPO(policy).play([g for _, g in group], [seeds] * len(group), greedy=mode == "greedy")
            for (regime, _), episodes in zip(group, played, strict=True):
                out[regime.name, mode] = [
                    raw.row(label, policy.config.seed, regime.path, regime.name, {"episode": k, **episode},
                            {"backend": "array"}) for k, episode in enumerate(episodes)]
    for group in groups.values():
        for _, played in group:
            played.close()
    return [row for regime in regimes for mode in args.modes for row in out[regime.name, mode]]


def add_price_argument(parser: argparse.ArgumentParser, what: str, price: float | None = None) -> None:
    price = RewardSettings().congestion_price if price is None else price
    parser.add_argument("--price", dest="congestion_price", type=congestion_price, default=price,
                        help=f"congestion price of the marginal reward{what} (default {price:g}; docs/reward.md)")


def main(argv: Sequence[str] | None = None) -> None:
    p = Parser(prog="python -m experiments.generalist", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True, parser_class=Parser)
    t = sub.add_parser("train", help="train one generalist across the training suite")
    t.add_argument("--suite", type=Path, required=True, help="the training suite (a folder of experiments.suite)")
    t.add_argument("--validation", type=Path, default=None,
                   help="the validation suite: scores every checkpoint, the best is best.pt")
    t.add_argument("--episodes", type=positive_int, default=200, help="training episodes (default 200)")
    t.add_argument("--checkpoint-every", type=positive_int, default=25, help="episodes between checkpoints (25)")
    t.add_argument("--validation-episodes", type=positive_int, default=2,
                   help="validation episodes per regime and checkpoint (default 2)")
    t.add_argument("--validation-mode", choices=MODES, default="greedy",
                   help="how the learner acts on validation: greedy (default: its most likely action, the evaluation "
                        "mode chosen on validation) or sampled")
    t.add_argument("--out", type=Path, default=Path("runs/generalist"), help="output folder (runs/generalist)")
    t.add_argument("--envs", type=positive_int, default=ENVS,
                   help=f"episodes run at once, K copies on the array backend (agents.vector_ppo: the same learner, "
                        f"fed in arrays; default {ENVS}); 1: the serial loop, one episode at a time on any backend")
    t.add_argument("--regimes", type=positive_int, default=None,
                   help="regimes drawn for each round of --envs episodes, each running --envs / --regimes of them "
                        f"(default {REGIMES} where it divides --envs, else 1)")
    s = sub.add_parser("specialist", help="train one PPO per regime of a suite (experiments.train ppo on each)")
    s.add_argument("--suite", type=Path, required=True, help="a suite folder: one specialist per regime")
    s.add_argument("--episodes", type=positive_int, default=100, help="training episodes per regime (default 100)")
    s.add_argument("--out", type=Path, default=Path("runs/specialists"), help="<out>/<regime>/ppo.pt")
    s.add_argument("--envs", type=positive_int, default=1,
                   help="episodes of a regime run at once (experiments.train --envs; default 1, the serial loop)")
    t.add_argument("--slots", type=positive_int, default=SLOTS,
                   help=f"neighbour slots: at least the largest degree of any regime it will meet (default {SLOTS})")
    for q, price in ((t, PRICE), (s, None)):
        add_backend_argument(q, "auto")
        q.add_argument("--max-steps", type=positive_int, default=None, help="steps per episode (default: the regime's)")
        add_price_argument(q, "", price)
        add_learner_arguments(q)
    e = sub.add_parser("evaluate", help="evaluate generalists, specialists and baselines on a suite: one CSV")
    e.add_argument("checkpoints", type=Path, nargs="*", help="generalist checkpoints (best.pt of each seed)")
    e.add_argument("--suite", type=Path, default=None, help="the suite to evaluate on (the test suite, once)")
    e.add_argument("--scenarios", nargs="*", default=[], metavar="SCENARIO",
                   help="scenarios of no suite to evaluate on too: bundled names (aot1 ...) or files")
    e.add_argument("--split", choices=SPLITS, default=None,
                   help="episode seeds of this set (default: the suite's; test without a suite)")
    e.add_argument("--specialists", type=Path, default=None, help="a folder of `specialist`: <regime>/ppo.pt")
    e.add_argument("--baselines", nargs="*", default=None, metavar="NAME",
                   help=f"baselines to run too, of {', '.join(BASELINES)} (--baselines alone: all of them)")
    e.add_argument("--tuned", type=Path, default=None,
                   help="a chosen.json of python -m experiments.tune_baselines: its baselines run too, as <name>_tuned")
    e.add_argument("--episodes", type=positive_int, default=5, help="episodes per regime (default 5)")
    e.add_argument("--max-steps", type=positive_int, default=None, help="steps per episode (default: the regime's)")
    e.add_argument("--modes", nargs="+", choices=MODES, default=["greedy"],
                   help="how learners act: greedy (default, chosen on validation: its most likely action, as "
                        "<policy>_greedy) and/or sampled (a sample of the learnt policy)")
    add_price_argument(e, ", for the return column")
    e.add_argument("--batched", action="store_true",
                   help="play a generalist's episodes of every regime at once, copies on the array backend "
                        "(agents.vector_ppo): greedy, the same episodes action for action, faster; "
                        "sampled, the same policy with another random stream. Baselines and specialists run as before")
    e.add_argument("--csv", type=Path, required=True, help="one row per policy, regime and episode")
    add_backend_argument(e, EVAL_BACKEND)
    e.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    e.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    args = p.parse_args(argv)
    {"train": train, "specialist": specialist, "evaluate": evaluate}[args.command](args, p)


if __name__ == "__main__":
    main()
