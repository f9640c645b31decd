"""Command-line plumbing shared by the experiment scripts: environment options, learner configs, overrides.

This is the layer that knows the environment (``env.ZenohEdgeEnv``); the agents themselves do not.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from typing import Any

import torch

from agents import LEARNERS, LearnerConfig
from env import ScenarioOverrides, ZenohEdgeEnv


def add_env_arguments(parser: argparse.ArgumentParser, scenario: bool = True) -> None:
    g = parser.add_argument_group("environment")
    if scenario:
        g.add_argument("--scenario", default="aot2", help="aot1..aot4 or a scenario YAML (default: aot2)")
        g.add_argument("--lam", type=float, default=0.17, help="task arrival rate lambda per source (default 0.17)")
    g.add_argument("--max-steps", type=int, default=None,
                   help="decision steps per episode (default: the scenario's, 1000; rq1/rq2 --quick: 300)")
    g.add_argument("--reward", default="paper", choices=["paper", "reference", "sparse"],
                   help="paper (default: Eq. 1-5 of the paper) or sparse (completed - dropped)")
    g.add_argument("--transport", default="inproc", choices=["inproc", "zenoh"],
                   help="inproc (default: one process, same results as zenoh) or zenoh (node processes)")


def add_learner_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("learning")
    g.add_argument("--seed", type=int, default=0, help="training seed: network initialisation and episodes (default 0)")
    g.add_argument("--hidden", type=int, nargs="+", default=None, help="hidden layer sizes (default 128 128)")
    g.add_argument("--set", dest="overrides", action="append", default=[], metavar="[ALGO.]FIELD=VALUE",
                   help="override a learner hyperparameter, e.g. --set ddqn.shared=true --set lr=1e-3 (repeatable)")
    g.add_argument("--device", default="cpu", help="cpu (default) or cuda (used only when available)")
    g.add_argument("--threads", type=int, default=1,
                   help="torch CPU threads (default 1: the networks are small, more threads only contend)")
    g.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bars")


def make_env(scenario: str, lam: float | None, max_steps: int, reward: str = "paper", transport: str = "inproc",
             seed: int = 0) -> ZenohEdgeEnv:
    """The environment every agent of a study runs in: padded spaces, so one network can serve all agents."""
    return ZenohEdgeEnv(scenario, transport=transport, overrides=ScenarioOverrides(arrival_rate=lam),
                        max_steps=max_steps, reward=reward, uniform_spaces=True, seed=seed)


def coerce(text: str, default: Any) -> Any:
    """A command-line string to the type of a config field's default value."""
    if isinstance(default, bool):
        if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
            raise ValueError(f"expected true or false, not {text!r}")
        return text.lower() in ("true", "1", "yes")
    if isinstance(default, tuple):
        return tuple(int(x) for x in text.split(","))
    if isinstance(default, int):
        return int(text)
    if isinstance(default, float) or default is None:
        return None if text.lower() == "none" else float(text)
    return text


def learner_config(algo: str, *, seed: int, hidden: Sequence[int] | None = None,
                   base: dict[str, Any] | None = None, overrides: Sequence[str] = ()) -> LearnerConfig:
    """``algo``'s config: its defaults, then ``base`` (e.g. quick mode's), hidden sizes, seed, then ``--set``s."""
    cls = LEARNERS[algo].Config
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    values: dict[str, Any] = dict(base or {})
    if hidden:
        values["hidden"] = tuple(hidden)
    values["seed"] = seed
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep:
            raise ValueError(f"--set {item!r}: expected [ALGO.]FIELD=VALUE")
        target, _, field = key.rpartition(".")
        if target and target not in LEARNERS:
            raise ValueError(f"--set {item!r}: unknown algorithm {target!r} ({', '.join(LEARNERS)})")
        if target and target != algo:
            continue
        if field not in defaults:
            if target or not any(field in {f.name for f in dataclasses.fields(c.Config)} for c in LEARNERS.values()):
                raise ValueError(f"--set {item!r}: {target or 'no learner'} has no field {field!r}")
            continue  # an unprefixed field applies to the learners that have it
        values[field] = coerce(text, defaults[field])
    return cls(**values)


def set_threads(n: int) -> None:
    torch.set_num_threads(max(1, n))
