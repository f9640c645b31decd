"""MAPPO on ZenohEdgeEnv through TorchRL: one actor shared by every agent, action masks, a centralised critic.

    python -m pip install -e ".[marl]"
    python examples/mappo_torchrl.py --scenario aot2 --frames 200000 --seed 0 --csv runs/mappo.csv
    python examples/mappo_torchrl.py --plot runs/mappo.csv --png mappo.png --baseline local=runs/local.csv
    python examples/mappo_torchrl.py --plot K=4=runs/k4.csv --plot K=100=runs/k100.csv --png mappo.png

The second form draws a learning curve against frames and against wall-clock seconds (``--baseline NAME=CSV``:
the rows ``python -m experiments.evaluate ... --csv`` writes, drawn as a level line); the third draws several
curves side by side (``--plot [LABEL=]CSV``, repeatable). Neither trains.

TorchRL's own multi-agent PPO recipe, in one file: ``env.vector.ZenohEdgeVectorEnv`` (``--envs`` K
simulations of ``observation="flat"`` stepped as one batch, on the array backend where it models the scenario:
``--backend``; with the keys of ``PettingZooWrapper`` and all agents in one group), ``MultiAgentMLP`` with
``share_params=True`` for the actor (the one-hot agent id in the observation tells the agents apart) and
``centralised=True`` for the critic (it sees every agent's observation), ``ProbabilisticActor`` with
``MaskedCategorical``, ``ClipPPOLoss`` with GAE and a ``Collector`` (TorchRL 0.14's name for
``SyncDataCollector``). A frame is one step of one simulation (every
agent acts once), so a batch of ``--frames-per-batch`` frames holds that many steps over the K simulations.

Every ``--eval-every`` batches the greedy policy (the most likely allowed action) plays ``--eval-episodes``
episodes on the seeds ``agents.training.evaluate`` uses (100000, 100001, ...), so its numbers compare with
``python -m experiments.evaluate <baseline> --scenario aot2 --max-steps 300 --reward sparse --episodes 5``.
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer, SamplerWithoutReplacement
from torchrl.envs import EnvBase, RewardSum, TransformedEnv
from torchrl.modules import MaskedCategorical, MultiAgentMLP, ProbabilisticActor
from torchrl.objectives import ClipPPOLoss, ValueEstimators

from agents.training import EVAL_SEED, episode_metrics
from env import ScenarioOverrides, ZenohEdgeEnv
from env.reward import REWARDS
from env.vector import ZenohEdgeVectorEnv
from experiments.common import BACKENDS, choose_backend

if TYPE_CHECKING:
    from matplotlib.figure import Figure

OBS = ("agents", "observation", "observation")  # where PettingZooWrapper and the vector env put the flat vector
MASK = ("agents", "action_mask")
# what the greedy evaluation reports, each the mean over its episodes (names as in experiments.evaluate's CSV)
EVAL_METRICS = ("return", "completed", "dropped", "completion_ratio", "response_time_mean", "penalised_response_time",
                "overloaded_node_ticks")


class SymLog(nn.Module):
    """sign(x) log(1 + |x|): the observation's units span decades (buffers up to 600, rates, seconds)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.sign(x) * torch.log1p(x.abs())


def settings(args: argparse.Namespace) -> dict:
    """What the training and the evaluation environments share; ``args.backend`` is resolved ("auto" chosen)."""
    return {"max_steps": args.max_steps, "reward": args.reward, "overrides": ScenarioOverrides(arrival_rate=args.lam),
            "backend": args.backend}


def make_env(args: argparse.Namespace, seed: int) -> ZenohEdgeEnv:
    """One simulation, for the greedy evaluation."""
    return ZenohEdgeEnv(args.scenario, transport="inproc", observation="flat", seed=seed, **settings(args))


def build(args: argparse.Namespace, env: EnvBase) -> tuple[ProbabilisticActor, TensorDictModule]:
    n_agents = len(env.group_map["agents"])
    n_obs = env.observation_spec[OBS].shape[-1]
    n_actions = env.full_action_spec["agents", "action"].space.n
    actor_net = nn.Sequential(SymLog(), MultiAgentMLP(
        n_agent_inputs=n_obs, n_agent_outputs=n_actions, n_agents=n_agents, centralised=False, share_params=True,
        depth=2, num_cells=args.hidden, activation_class=nn.Tanh))
    actor = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=[OBS], out_keys=[("agents", "logits")]),
        in_keys={"logits": ("agents", "logits"), "mask": MASK}, out_keys=[("agents", "action")],
        distribution_class=MaskedCategorical, return_log_prob=True, log_prob_key=("agents", "action_log_prob"))
    critic_net = nn.Sequential(SymLog(), MultiAgentMLP(
        n_agent_inputs=n_obs, n_agent_outputs=1, n_agents=n_agents, centralised=True, share_params=True,
        depth=2, num_cells=args.hidden, activation_class=nn.Tanh))
    critic = TensorDictModule(critic_net, in_keys=[OBS], out_keys=[("agents", "state_value")])
    return actor, critic


@torch.no_grad()
def greedy_actions(actor: ProbabilisticActor, observations: dict, agents: list[str]) -> dict[str, int]:
    """The most likely allowed action of every agent (all agents in one batch, as in training)."""
    x = torch.as_tensor(np.stack([observations[a]["observation"] for a in agents]))
    mask = torch.as_tensor(np.stack([observations[a]["action_mask"] for a in agents]), dtype=torch.bool)
    logits = actor.module[0].module(x).masked_fill(~mask, -math.inf)
    return dict(zip(agents, logits.argmax(-1).tolist(), strict=True))


def evaluate(actor: ProbabilisticActor, env: ZenohEdgeEnv, episodes: int) -> dict[str, float]:
    """Mean metrics of the greedy policy over the evaluation seeds, as agents.training.evaluate reports them."""
    rows = []
    for k in range(episodes):
        observations, _ = env.reset(seed=EVAL_SEED + k)
        total = 0.0
        while env.agents:
            observations, rewards, *_ = env.step(greedy_actions(actor, observations, env.possible_agents))
            total += sum(rewards.values())
        rows.append({"return": total, **episode_metrics(env.step_details[env.possible_agents[0]]["episode"])})
    return {f"eval_{k}": float(np.mean([r[k] for r in rows])) for k in EVAL_METRICS}


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="aot2", help="aot1..aot4 or a scenario YAML (default aot2)")
    p.add_argument("--frames", type=int, default=60_000, help="environment steps to train for (default 60000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the networks and of the training episodes")
    p.add_argument("--max-steps", type=int, default=300, help="steps per episode (default 300)")
    p.add_argument("--lam", type=float, default=0.17, help="task arrival rate per source (default 0.17)")
    p.add_argument("--reward", default="sparse", choices=list(REWARDS), help="default sparse (docs/reward.md)")
    p.add_argument("--backend", default="auto", choices=BACKENDS,
                   help="auto (default: the array backend where it models the scenario, else the emulator; one line "
                        "on stderr says which), array or emulator (docs/env.md, \"Backends\"); training and greedy "
                        "evaluation both run on it")
    p.add_argument("--envs", type=int, default=4,
                   help="simulations stepped together (K; default 4); simulation k's episodes are seeded from seed + k")
    p.add_argument("--frames-per-batch", type=int, default=1200,
                   help="steps collected per update, over all simulations (default 1200; a multiple of --envs)")
    p.add_argument("--epochs", type=int, default=4, help="passes over each batch (default 4)")
    p.add_argument("--minibatch", type=int, default=400, help="steps per gradient step (default 400)")
    p.add_argument("--lr", type=float, default=3e-4)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--lmbda", type=float, default=0.95)
    p.add_argument("--clip", type=float, default=0.2)
    p.add_argument("--entropy", type=float, default=1e-3, help="entropy bonus coefficient (default 1e-3)")
    p.add_argument("--hidden", type=int, default=128, help="units per hidden layer (default 128)")
    p.add_argument("--eval-every", type=int, default=5, help="batches between greedy evaluations (0: at the end only)")
    p.add_argument("--eval-episodes", type=int, default=3, help="episodes per evaluation (default 3)")
    p.add_argument("--csv", type=Path, default=None, help="write the learning curve here, one row per batch")
    p.add_argument("--plot", action="append", default=[], metavar="[LABEL=]CSV",
                   help="draw this learning-curve CSV (repeatable: the curves side by side; with --png) and exit")
    p.add_argument("--png", type=Path, default=None, help="the picture --plot draws")
    p.add_argument("--baseline", action="append", default=[], metavar="NAME=CSV",
                   help="an experiments.evaluate CSV to draw as a level line (repeatable)")
    args = p.parse_args(argv)
    if args.envs < 1 or args.frames_per_batch % args.envs:
        p.error(f"--envs must be >= 1 and divide --frames-per-batch (got {args.envs} and {args.frames_per_batch})")
    for item in args.plot + args.baseline:
        if not labelled(item)[1].is_file():
            p.error(f"{labelled(item)[1]}: no such CSV file")
    if not args.plot:
        args.backend = choose_backend(p.prog, [(args.scenario, args.lam)], args.backend)[args.scenario, args.lam]
    return args


def train(args: argparse.Namespace) -> tuple[dict[str, float], ProbabilisticActor]:
    """Train; returns the last batch's row of the learning curve and the trained actor."""
    torch.manual_seed(args.seed)
    torch.set_num_threads(1)  # small networks: more threads only contend with the simulation

    vector = ZenohEdgeVectorEnv(args.scenario, num_envs=args.envs, seed=args.seed, **settings(args))
    env = TransformedEnv(vector, RewardSum(in_keys=[("agents", "reward")], out_keys=[("agents", "episode_reward")]))
    actor, critic = build(args, env)
    collector = Collector(env, actor, frames_per_batch=args.frames_per_batch, total_frames=args.frames)
    buffer = ReplayBuffer(storage=LazyTensorStorage(args.frames_per_batch), sampler=SamplerWithoutReplacement(),
                          batch_size=args.minibatch)
    loss_module = ClipPPOLoss(actor_network=actor, critic_network=critic, clip_epsilon=args.clip,
                              entropy_coeff=args.entropy, normalize_advantage=False)
    loss_module.set_keys(reward=("agents", "reward"), action=("agents", "action"),
                         sample_log_prob=("agents", "action_log_prob"), value=("agents", "state_value"),
                         done=("agents", "done"), terminated=("agents", "terminated"))
    loss_module.make_value_estimator(ValueEstimators.GAE, gamma=args.gamma, lmbda=args.lmbda)
    optim = torch.optim.Adam(loss_module.parameters(), lr=args.lr)
    eval_env = make_env(args, args.seed)

    writer = None
    if args.csv:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        out = open(args.csv, "w", newline="")  # noqa: SIM115 - rows are flushed one by one, closed at the end
    start, frames, row = time.perf_counter(), 0, {}
    batches = math.ceil(args.frames / args.frames_per_batch)
    waited = start  # when the collector was last asked for a batch
    for i, data in enumerate(collector):
        collected = time.perf_counter()
        frames += data.numel()
        done = data["next", "agents", "done"].squeeze(-1).all(-1)  # episodes that ended in this batch
        episode_return = data["next", "agents", "episode_reward"].squeeze(-1).sum(-1)[done]
        completed = data["next", "agents", "info", "node_completed"].sum(-1)[done]
        with torch.no_grad():
            loss_module.value_estimator(data, params=loss_module.critic_network_params,
                                        target_params=loss_module.target_critic_network_params)
        buffer.extend(data.reshape(-1))
        for _ in range(args.epochs):
            for _ in range(args.frames_per_batch // args.minibatch):
                losses = loss_module(buffer.sample())
                loss = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
                loss.backward()
                nn.utils.clip_grad_norm_(loss_module.parameters(), 1.0)
                optim.step()
                optim.zero_grad()
        collector.update_policy_weights_()
        updated = time.perf_counter()
        row = {"batch": i, "frames": frames, "wall_s": round(updated - start, 1),
               "collect_s": round(collected - waited, 3), "update_s": round(updated - collected, 3),
               "train_return": float(episode_return.mean()) if done.any() else math.nan,
               "train_completed": float(completed.mean()) if done.any() else math.nan,
               **{k: losses[k].item() for k in ("loss_objective", "loss_critic", "loss_entropy")}}
        if (args.eval_every and (i + 1) % args.eval_every == 0) or i + 1 == batches:
            row |= evaluate(actor, eval_env, args.eval_episodes)
        print(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()), flush=True)
        if args.csv:
            if writer is None:
                writer = csv.DictWriter(out, fieldnames=["batch", "frames", "wall_s", "collect_s", "update_s",
                                                         "train_return", "train_completed",
                                                         "loss_objective", "loss_critic", "loss_entropy",
                                                         *(f"eval_{k}" for k in EVAL_METRICS)])
                writer.writeheader()
            writer.writerow(row)
            out.flush()
        waited = time.perf_counter()
    collector.shutdown()
    eval_env.close()
    if args.csv:
        out.close()
    return row, actor


def labelled(item: str) -> tuple[str, Path]:
    """``LABEL=CSV`` (the label may hold "=": the path is what follows the last one) or ``CSV`` (labelled by the
    file's name) as (label, path)."""
    label, sep, path = item.rpartition("=")
    return (label, Path(path)) if sep else (Path(item).stem, Path(item))


def plot(curves: list[str], png: Path, baselines: list[str]) -> Figure:
    """The greedy evaluations' completion, score and return of each curve (``[LABEL=]CSV``), beside the baselines'
    means: against frames (top row) and against wall-clock seconds (bottom row: what another backend or K buys)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def rows(path: Path) -> list[dict[str, str]]:
        with open(path) as f:
            return list(csv.DictReader(f))

    panels = (("completion_ratio", "tasks completed (share of generated)"),
              ("penalised_response_time", "score: penalised response time (s, lower is better)"),
              ("return", "return per episode (sum over agents)"))
    xs = (("frames", "frames (simulation steps)"), ("wall_s", "wall-clock (s, training and evaluations)"))
    evaluated = [(label, [r for r in rows(path) if r["eval_return"]]) for label, path in map(labelled, curves)]
    tables = [(name, rows(path)) for name, path in map(labelled, baselines)]
    levels = {metric: [(name, float(np.mean([float(r[metric]) for r in table]))) for name, table in tables]
              for metric, _ in panels}
    fig, axes = plt.subplots(len(xs), len(panels), figsize=(15, 8), squeeze=False)
    for (x, xlabel), row in zip(xs, axes, strict=True):
        for ax, (metric, title) in zip(row, panels, strict=True):
            for c, (label, points) in enumerate(evaluated):
                ax.plot([float(r[x]) for r in points], [float(r[f"eval_{metric}"]) for r in points],
                        marker="o", ms=3, color=f"C{c}", label=f"{label} (greedy)")
            for b, (name, level) in enumerate(levels[metric]):
                ax.axhline(level, ls="--", lw=1, color=f"C{len(evaluated) + b}", label=name)
            ax.set(xlabel=xlabel, title=title)
    axes[0, -1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    return fig


if __name__ == "__main__":
    arguments = parse()
    if arguments.plot:
        plot(arguments.plot, arguments.png or labelled(arguments.plot[0])[1].with_suffix(".png"), arguments.baseline)
    else:
        train(arguments)
