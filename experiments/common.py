"""Command-line plumbing shared by the experiment scripts: environment options, learner configs, overrides.

This is the layer that knows the environment (``env.ZenohEdgeEnv``); the agents themselves do not.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import sys
from collections.abc import Collection, Sequence
from typing import Any, NoReturn

import torch

from agents import LEARNERS, LearnerConfig
from env import MAX_SEED, ScenarioOverrides, Unsupported, ZenohEdgeEnv
from env.reward import REWARDS, RewardSettings
from orchestrator.scenario.errors import ScenarioError


class Parser(argparse.ArgumentParser):
    """The experiment CLIs' parser: a user's mistake is one line on stderr and exit status 2, no usage dump."""

    def error(self, message: str) -> NoReturn:
        usage_error(self.prog, message)


def usage_error(prog: str, message: str) -> NoReturn:
    """What the user must fix, as one line, and exit status 2 (argparse's for bad arguments)."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def _number(text: str, kind: type, ok: Any, expected: str) -> Any:
    try:
        value = kind(text)
    except ValueError:
        value = None
    if value is None or not ok(value):
        raise argparse.ArgumentTypeError(f"expected {expected}, not {text!r}")
    return value


def positive_int(text: str) -> int:
    return _number(text, int, lambda v: v >= 1, "an integer >= 1")


def seed_int(text: str) -> int:
    return _number(text, int, lambda v: 0 <= v <= MAX_SEED, f"an integer from 0 to {MAX_SEED}")


def positive_number(text: str) -> float:
    return _number(text, float, lambda v: 0 < v < float("inf"), "a number > 0")


def rate(text: str) -> float:
    return _number(text, float, lambda v: 0 <= v < float("inf"), "an arrival rate >= 0 (tasks/s per source)")


def congestion_price(text: str) -> float:
    """``--price``: a number that ``RewardSettings`` takes (the environment's own, and only, check of it)."""
    value = _number(text, float, lambda v: True, "a number")
    try:
        return RewardSettings(congestion_price=value).congestion_price
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


BACKENDS = ("emulator", "array", "auto")  # --backend: the node code, the array backend, or the second where it applies
# evaluation's default too: the array backend gives the emulator's episodes exactly (tests/test_array_env.py), so a
# policy scores the same on either (tests/test_backends.py); the emulator stays one --backend away
EVAL_BACKEND = "auto"


def add_env_arguments(parser: argparse.ArgumentParser, scenario: bool = True, reward: str | None = "paper",
                      reward_default_help: str | None = None, backend: str = "auto") -> None:
    """``reward``: the command's default reward (the studies reproduce the paper's); ``reward_default_help``
    says what the default is when the command decides it later (training: per learner); ``backend``: the
    command's default backend."""
    g = parser.add_argument_group("environment")
    if scenario:
        g.add_argument("--scenario", default="aot2",
                       help="a bundled scenario (aot1..aot4, aot3_compute, ...) or a scenario YAML (default: aot2)")
        g.add_argument("--lam", type=rate, default=None,
                       help="a constant task arrival rate lambda per source "
                            "(default: the scenario's; 0.17 in aot1..aot4)")
    g.add_argument("--max-steps", type=positive_int, default=None,
                   help="decision steps per episode (default: the scenario's, 1000; rq1/rq2 --quick: 300)")
    g.add_argument("--reward", default=reward, choices=list(REWARDS),
                   help=f"default: {reward_default_help or reward}. paper (Eq. 1-5 of the paper), "
                        "reference (the reference implementation's), sparse (completed - dropped at the "
                        "agent's node), team (the same, network-wide, shared by all agents), score (each of "
                        "the node's own tasks that completes earns 1 - response / penalty: the headline score, "
                        "credited to the origin), team_score (the same, network-wide) or marginal (score minus "
                        "the delay the agent's decisions imposed on other tasks, priced: a difference reward); "
                        "docs/reward.md")
    g.add_argument("--price", dest="congestion_price", type=congestion_price,
                   default=RewardSettings().congestion_price,
                   help=f"the congestion price c of the marginal reward and of the credits per task: what a "
                        f"deadline's worth of waiting imposed on another task costs, in completions (default "
                        f"{RewardSettings().congestion_price:g}; docs/reward.md)")
    g.add_argument("--transport", default="inproc", choices=["inproc", "zenoh"],
                   help="inproc (default: one process, same results as zenoh) or zenoh (node processes), for the "
                        "emulator backend")
    add_backend_argument(g, backend)


def add_backend_argument(parser: argparse.ArgumentParser | argparse._ArgumentGroup, default: str) -> None:
    parser.add_argument("--backend", default=default, choices=BACKENDS,
                        help=f"default: {default}. auto (the array backend where it models the scenario, else the "
                             "emulator; one line on stderr says which and why), array (the model as arrays in this "
                             "process: the same results, faster) or emulator (the node code, over --transport); "
                             "docs/env.md, \"Backends\"")


def add_learner_arguments(parser: argparse.ArgumentParser, seeds: bool = False) -> None:
    """The learners' options; with ``seeds``, ``--seed`` takes several training seeds (``args.seeds``)."""
    g = parser.add_argument_group("learning")
    if seeds:
        g.add_argument("--seed", dest="seeds", type=seed_int, nargs="+", default=[0], metavar="SEED",
                       help="training seeds: every point of the sweep is run once per seed (default 0)")
    else:
        g.add_argument("--seed", type=seed_int, default=0,
                       help="training seed: network initialisation and episodes (default 0)")
    g.add_argument("--hidden", type=positive_int, nargs="+", default=None,
                   help="hidden layer sizes (default 128 128)")
    g.add_argument("--set", dest="overrides", action="append", default=[], metavar="[ALGO.]FIELD=VALUE",
                   help="override a learner hyperparameter, e.g. --set ddqn.shared=true --set lr=1e-3 (repeatable)")
    g.add_argument("--device", default="cpu", help="cpu (default) or cuda (used only when available)")
    g.add_argument("--threads", type=positive_int, default=1,
                   help="torch CPU threads (default 1: the networks are small, more threads only contend)")
    g.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bars")


def make_env(scenario: str, lam: float | None, max_steps: int | None, reward: str = "paper",
             transport: str = "inproc", seed: int = 0, congestion_price: float | None = None,
             backend: str = "emulator", flat: bool = False) -> ZenohEdgeEnv:
    """The environment every agent of a study runs in: padded spaces, so one network can serve all agents.
    ``congestion_price``: None for the environment's default; ``backend``: "emulator" or "array" (``choose_backend``
    resolves "auto"); ``flat``: flat observations without info numbers, what ``agents.vector_ppo`` steps."""
    shape = {"observation": "flat", "info_numbers": False} if flat else {}
    return ZenohEdgeEnv(scenario, backend=backend, transport=transport, overrides=ScenarioOverrides(arrival_rate=lam),
                        max_steps=max_steps, reward=reward, uniform_spaces=True, seed=seed,
                        congestion_price=congestion_price, **shape)


def coerce(text: str, default: Any) -> Any:
    """A command-line string to the type of a config field's default value."""
    if isinstance(default, bool):
        if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
            raise ValueError(f"expected true or false, not {text!r}")
        return text.lower() in ("true", "1", "yes")
    try:
        if isinstance(default, tuple):
            return tuple(int(x) for x in text.split(","))
        if isinstance(default, int):
            return int(text)
        if isinstance(default, float) or default is None:
            return None if text.lower() == "none" else float(text)
    except ValueError:
        kind = "integers separated by commas" if isinstance(default, tuple) else (
            "an integer" if isinstance(default, int) else "a number or none")
        raise ValueError(f"expected {kind}, not {text!r}") from None
    return text


# what a learner trained on the marginal reward uses unless told otherwise: each decision is learnt
# from its own tasks' credit, which prices every wait it causes, so nothing after it is added (gamma 0); the
# credits are normalised, since reward_scale is tuned for the paper reward's magnitudes
TASK_CREDIT: dict[str, Any] = {"credit": "task", "gamma": 0.0, "normalize_reward": True}


def learner_config(algo: str, *, seed: int, reward: str, hidden: Sequence[int] | None = None,
                   base: dict[str, Any] | None = None, overrides: Sequence[str] = (),
                   chosen: Collection[str] = ()) -> LearnerConfig:
    """``algo``'s config: its defaults, then ``base`` (e.g. quick mode's), hidden sizes, seed, then ``--set``s.

    On the ``marginal`` reward a learner that can (PPO, A2C, DDQN) learns from each decision's own credit
    (``TASK_CREDIT``: env.credit, docs/agents.md "Credit per task"), which is that reward's per-task account.

    ``chosen`` are the algorithms this run trains (default: ``algo`` alone). An ``--set`` must reach one of them:
    a prefix names one of them and a field it has, an unprefixed field belongs to at least one of them (and
    applies to those that have it). Anything else is a ValueError with one line for the user."""
    chosen = set(chosen) | {algo}
    cls = LEARNERS[algo].Config
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    values: dict[str, Any] = dict(TASK_CREDIT) if reward == "marginal" and LEARNERS[algo].task_credit else {}
    values.update(base or {})
    if hidden:
        values["hidden"] = tuple(hidden)
    values["seed"] = seed
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep:
            raise ValueError(f"--set {item!r}: expected [ALGO.]FIELD=VALUE")
        target, _, name = key.rpartition(".")
        if target and target not in LEARNERS:
            raise ValueError(f"--set {item!r}: unknown algorithm {target!r}{_suggest(target, LEARNERS)} "
                             f"(one of {', '.join(LEARNERS)})")
        if target and target not in chosen:
            raise ValueError(f"--set {item!r}: {target} is not trained in this run ({', '.join(sorted(chosen))})")
        owners = [a for a in ([target] if target else sorted(chosen)) if name in _fields(a)]
        if not owners:
            others = [a for a in LEARNERS if a not in chosen and name in _fields(a)]
            known = set().union(*(_fields(a) for a in ([target] if target else chosen)))
            lacks = (f"{target or next(iter(chosen))} has no field" if target or len(chosen) == 1 else
                     f"none of {', '.join(sorted(chosen))} has a field")
            raise ValueError(f"--set {item!r}: {lacks} {name!r}" + (
                f" (it is a field of {', '.join(others)})" if others else _suggest(name, known)))
        if algo not in owners:
            continue
        try:
            values[name] = coerce(text, defaults[name])
        except ValueError as e:
            raise ValueError(f"--set {item!r}: {e}") from None
    if values.get("credit") == "task" and reward != "marginal":
        raise ValueError(f"{algo}: credit=task learns from the marginal reward's credits per task, not from "
                         f"{reward!r}: train on --reward marginal, or leave credit at step")
    try:
        return cls(**values)
    except ValueError as e:  # a value of the right type that the learner refuses (an unknown teacher ...)
        raise ValueError(f"{algo}: {e}") from None


def _fields(algo: str) -> set[str]:
    return {f.name for f in dataclasses.fields(LEARNERS[algo].Config)}


def _suggest(word: str, choices: Collection[str]) -> str:
    hint = difflib.get_close_matches(word, list(choices), n=1)
    return f" (did you mean {hint[0]!r}?)" if hint else ""


def check_scenario(prog: str, scenario: str, lam: float | None, backend: str = "emulator",
                   transport: str = "inproc") -> tuple[str, str]:
    """Load ``scenario`` once before any work starts; a file that is missing or wrong, or one that ``--backend
    array`` does not model, is the user's error. Returns the backend it runs on ("auto" resolved: the array
    backend where the scenario's own check lets it, else the emulator) and why, in a few words."""
    if backend == "array" and transport != "inproc":
        usage_error(prog, f"--backend array runs in this process: --transport {transport} applies to the emulator")
    asked = backend
    if asked == "auto":
        backend, why = (("array", "it models this scenario: the emulator's results, step for step")
                        if transport == "inproc" else ("emulator", f"--transport {transport} runs the node code"))
    else:
        why = f"--backend {asked}"
    try:
        try:
            make_env(scenario, lam, None, transport=transport, backend=backend).close()
        except Unsupported as e:
            if asked != "auto":
                usage_error(prog, str(e))
            backend, why = "emulator", str(e).partition(";")[0]
            make_env(scenario, lam, None, transport=transport, backend=backend).close()
    except ScenarioError as e:
        usage_error(prog, str(e).replace("\n", "; "))
    return backend, why


def choose_backend(prog: str, scenarios: Sequence[tuple[str, float | None]], backend: str,
                   transport: str = "inproc") -> dict[tuple[str, float | None], str]:
    """Each (scenario, rate)'s backend, every scenario checked (``check_scenario``); with ``--backend auto``, one
    line on stderr says which backend the run uses and why."""
    chosen = {point: check_scenario(prog, *point, backend, transport) for point in dict.fromkeys(scenarios)}
    if backend == "auto":
        print(f"{prog}: {backend_line(list(chosen.values()))}", file=sys.stderr)
    return {point: b for point, (b, _) in chosen.items()}


def backend_line(chosen: Sequence[tuple[str, str]]) -> str:
    """What ``--backend auto`` chose for a run's scenarios, in one line: the backend, and why."""
    refused = [why for b, why in chosen if b == "emulator"]
    if not refused:
        why = chosen[0][1] if len(chosen) == 1 else "it models every scenario: the emulator's results, step for step"
        return f"--backend auto: the array backend ({why})"
    if len(refused) == len(chosen) == 1:
        return f"--backend auto: the emulator ({refused[0]})"
    return (f"--backend auto: the array backend for {len(chosen) - len(refused)} of {len(chosen)} scenarios, the "
            f"emulator for {len(refused)} (first: {refused[0]})")


def set_threads(n: int) -> None:
    torch.set_num_threads(max(1, n))
