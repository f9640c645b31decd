"""Regime cards: what the baselines achieve in each scenario family, at two arrival rates.

A card says which regime a family is in before anyone trains on it: whether offloading pays (does any
heuristic complete more than `local`?) and whether one heuristic dominates (is the same baseline best
on completion and on the score?). Where one does, a learner has little to learn.

    python -m experiments.regimes                          # every family; writes docs/regimes/
    python -m experiments.regimes --families compute wired --episodes 3 --out runs/regimes

Every baseline runs the same evaluation episodes (seeds 100000, 100001, ..., as experiments.evaluate)
with the scenario's own episode length. Outputs under ``--out``: ``<family>.csv`` (one raw row,
``experiments.raw``, per rate, baseline and episode) and ``README.md`` (the cards, made from those rows).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents import BASELINES, evaluate
from agents.training import EVAL_SEED, progress_bar, write_csv
from experiments import raw
from experiments.common import Parser, check_scenario, make_env, positive_int
from experiments.plot import mean_ci

Column = tuple[str, str, float, str | None]
"""A column of a card: metric, header, scale, and which way is better (None: not judged alone, see the card)."""


@dataclass(frozen=True)
class Family:
    """A bundled scenario standing for a family, and the arrival rates its card is measured at (None: the
    scenario's own schedule, as for the regimes of ``experiments.suite``). ``columns``: what its card shows
    after the task metrics (``METRICS``), for what only its scenario has (jobs, broken links)."""

    name: str
    scenario: str
    lambdas: tuple[float | None, ...]
    about: str
    columns: tuple[Column, ...] = ()


JOB_COLUMNS: tuple[Column, ...] = (
    ("jobs", "jobs", 1.0, None), ("job_completion_ratio", "jobs done %", 100.0, "max"),
    ("jobs_missed", "jobs missed", 1.0, "min"), ("makespan_mean", "makespan [s]", 1.0, None),
    ("penalised_makespan", "job score [s]", 1.0, "min"))
"""A scenario of jobs: the job metrics (``agents.training.JOB_METRICS``), jobs created to the penalised makespan."""
DROP_COLUMNS: tuple[Column, ...] = (
    ("dropped_queue_full", "queue full", 1.0, "min"), ("dropped_expired", "expired", 1.0, "min"),
    ("dropped_link_broken", "link broken", 1.0, "min"))
"""Moving nodes: the drops by cause, those lost on a link that broke among them."""
FAMILIES = (
    Family("paper", "aot3", (0.17, 0.35),
           "The paper's Table as this project reads it: 8e7 instructions, 150 MiB in and out, 100 s deadlines, "
           "radio links of 24-36 Mbit/s. An offload costs a minute of transfer for 20 s of compute."),
    Family("reference", "aot3_reference", (0.17, 0.35),
           "What the reference implementation ran: 3.2e8 instructions, 150 MB in and out, deadlines U[100, 200) "
           "+ 5 s, free-space radio, queue-first workers, control latency 0."),
    Family("compute", "aot3_compute", (0.03, 0.06),
           "Heavy compute, small data: 2e8 instructions (50 s on an rpi3, 2.3 s on the server), 2 MB in, "
           "200 kB out, deadlines U[40, 80) s. Capacity runs out near lambda = 0.07."),
    Family("wired", "aot3_wired", (0.1, 0.2),
           "The paper's task over the Ether file's wired rates: 500 Mbit/s to the cluster's nuc, 25 Mbit/s "
           "each way to the server, whose 100 s round trip misses the 100 s deadline. The nucs saturate first."),
    Family("urgent", "aot3_urgent", (0.03, 0.04),
           "Urgent alerts beside tolerant batch work: compute's task (2e8 instructions, 2 MB in, 200 kB out), "
           "half with deadlines U[10, 20) s, which only the server or a nuc meets, half U[100, 200) s, which an "
           "idle rpi3 meets too. The nucs and the server run out near lambda = 0.05."),
    Family("dag", "examples/dag_jobs", (0.01, 0.02),
           "Jobs as DAGs (docs/model.md): aot2's 19 nodes, each arrival (lambda jobs/s per rpi3) a random layered "
           "DAG of 3-15 tasks of 1-3e7 instructions whose edges carry 5-20 MB, 150 s for the whole job. A task "
           "is placed when it is ready, so one job's tasks spread over nodes. The task columns count the tasks "
           "of every job; jobs done % and the job score (mean makespan, the 150 s deadline for a job not "
           "completed) judge the jobs.", JOB_COLUMNS),
    Family("mobile", "examples/mobile", (0.1, 0.3),
           "Moving nodes (docs/model.md): six devices (1e7 instructions/s) move through a 600 m x 300 m "
           "district past three wired servers (2e7 x 4), offloading over the radio within 150 m; a transfer "
           "whose link breaks is lost (link broken). Tasks of 4e7 instructions (4 s on a device), 1 MB in, "
           "20 s deadlines; 600 steps. A device's own CPU runs out at lambda = 0.25.", DROP_COLUMNS),
)
NO_CARD = ("Payloads (`examples/payload_classifier`, [docs/extending.md](../extending.md#real-work-in-the-loop)) "
           "have no card: their service times are the CPU times a run measures, so the same seeds give other "
           "numbers on another machine or under another load, where a card holds only what the seeds fix. A "
           "record of the measured times replays only the recorded run's own placements, not another "
           "baseline's, and measuring takes about 15 s an episode (41 ticks/s), some 14 minutes for a card's "
           "54 episodes.")
"""What the page says of the feature without a family."""
METRICS: tuple[Column, ...] = (
    ("completion_ratio", "completion %", 100.0, "max"), ("response_time_mean", "response [s]", 1.0, None),
    ("dropped", "dropped", 1.0, "min"), ("penalised_response_time", "score [s]", 1.0, "min"))
"""The columns of every card."""


def rate_label(lam: float | None) -> str:
    return "own" if lam is None else f"{lam:g}"


def measure(family: Family, episodes: int, max_steps: int | None = None, progress: Any = None,
            seed: int = EVAL_SEED) -> list[dict[str, Any]]:
    """One raw row (``experiments.raw``) per rate, baseline and evaluation episode (seeds ``seed``, ``seed`` + 1,
    ...), with the family, its scenario and the rate. No wall time: the files are kept in git, and hold only what
    the seed fixes."""
    rows = []
    for lam in family.lambdas:
        env = make_env(family.scenario, lam, max_steps)
        regime = family.name if lam is None else f"{Path(family.scenario).stem}-lam{lam:g}"
        try:
            for name, cls in BASELINES.items():
                label = f"{family.name} λ={rate_label(lam)} {name}"
                rows += [raw.row(name, None, family.scenario, regime, r,
                                 {"family": family.name, "scenario": family.scenario, "lambda": lam})
                         for r in evaluate(env, cls(0), episodes, seed=seed, progress=progress, label=label)]
        finally:
            env.close()
    return rows


def read_rows(path: Path) -> list[dict[str, Any]]:
    """A family's CSV as written by ``measure``, numbers as floats (the episode index as an int)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        for k, v in r.items():
            if k not in ("family", "scenario", *raw.TEXT):
                r[k] = int(v) if k in ("episode", "steps") else float(v) if v else math.nan
    return rows


def card(family: Family, rows: Sequence[dict[str, Any]]) -> str:
    """A family's card in Markdown: the mean ± 95% CI per baseline and rate, the best in bold, a verdict.
    The baselines are those the rows hold, in ``BASELINES`` order."""
    episodes = len({r["episode"] for r in rows})
    steps = rows[0]["steps"]
    names = [b for b in BASELINES if any(r["policy"] == b for r in rows)]
    lines = [f"## {family.name}: `{family.scenario}`", "", family.about, "",
             f"{len(names)} baselines, {episodes} evaluation episodes of {steps} steps each (mean ± 95% CI). "
             "Score: mean time per generated task, a task not completed counts its deadline (lower is better).", ""]
    columns = (*METRICS, *family.columns)
    header = ["λ", "baseline", *(title for _, title, _, _ in columns)]
    lines += ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    for lam in family.lambdas:
        at = [r for r in rows if _same(r["lambda"], lam)]
        stats = {(b, m): mean_ci([r[m] * scale for r in at if r["policy"] == b])
                 for b in names for m, _, scale, _ in columns}
        best = {m: (max if way == "max" else min)(names, key=lambda b, m=m: stats[b, m][0])
                for m, _, _, way in columns if way}
        for b in names:
            cells = []
            for m, _, _, _ in columns:
                mean, ci = stats[b, m]
                text = f"{mean:.1f} ± {ci:.1f}"
                cells.append(f"**{text}**" if best.get(m) == b else text)
            lines.append(f"| {rate_label(lam)} | {b} | " + " | ".join(cells) + " |")
        lines.append(f"| {rate_label(lam)} | | {verdict(stats, best)} |" + " |" * (len(columns) - 1))
    return "\n".join(lines) + "\n"


def _same(value: Any, lam: float | None) -> bool:
    """A row's rate is the card's: a number, or the scenario's own (None in memory, NaN read back from a CSV)."""
    if lam is None:
        return value is None or (isinstance(value, float) and math.isnan(value))
    return value == lam


def verdict(stats: dict[tuple[str, str], tuple[float, float]], best: dict[str, str]) -> str:
    """Does offloading pay, and does one heuristic dominate? Read off the means, with no tuning. In a scenario
    of jobs (``best`` judges ``job_completion_ratio``) the same for the jobs: completed, and the job score."""
    lead = best["completion_ratio"]
    first = _gain(stats, lead, "completion_ratio")
    if best["completion_ratio"] == best["penalised_response_time"] == best["dropped"]:
        tasks = f"{first}; {lead} dominates"
    else:
        tasks = (f"{first}; no heuristic dominates: most completed {lead}, best score "
                 f"{best['penalised_response_time']}, fewest dropped {best['dropped']}")
    if "job_completion_ratio" not in best:
        return f"*{tasks}*"
    lead, score = best["job_completion_ratio"], best["penalised_makespan"]
    jobs = _gain(stats, lead, "job_completion_ratio")
    jobs += (f"; {lead} dominates" if lead == score else
             f"; no heuristic dominates: most jobs done {lead}, best job score {score}")
    return f"*tasks: {tasks}. Jobs: {jobs}*"


def _gain(stats: dict[tuple[str, str], tuple[float, float]], lead: str, metric: str) -> str:
    """Whether the baseline that completes most (``lead``, on ``metric``, a ratio) beats ``local`` beyond the CIs."""
    (top, top_ci), (local, local_ci) = stats[lead, metric], stats["local", metric]
    if lead == "local":
        return "keeping tasks local is best"
    if top - top_ci > local + local_ci:
        return f"offloading pays (+{top - local:.1f} points over local)"
    return f"offloading barely matters (+{top - local:.1f} points over local, within the 95% CIs)"


def main(argv: Sequence[str] | None = None) -> None:
    p = Parser(prog="python -m experiments.regimes", description=__doc__.splitlines()[0])
    names = [f.name for f in FAMILIES]
    p.add_argument("--families", nargs="+", choices=names, default=names, metavar="FAMILY",
                   help=f"families to measure (default: all of {', '.join(names)})")
    p.add_argument("--episodes", type=positive_int, default=3, help="evaluation episodes per baseline (default 3)")
    p.add_argument("--max-steps", type=positive_int, default=None,
                   help="steps per episode (default: the scenario's, 1000; shorter only to try the command)")
    p.add_argument("--out", type=Path, default=Path("docs/regimes"), help="output directory (default docs/regimes)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.add_argument("--cards-only", action="store_true",
                   help="rebuild README.md from the CSV files already in --out, without running anything")
    args = p.parse_args(argv)
    chosen = [f for f in FAMILIES if f.name in args.families]
    cards = []
    if args.cards_only:
        for family in chosen:
            try:
                cards.append(card(family, read_rows(args.out / f"{family.name}.csv")))
            except FileNotFoundError:
                p.error(f"{args.out / f'{family.name}.csv'}: not found; run without --cards-only first")
    else:
        for family in chosen:
            check_scenario(p.prog, family.scenario, None)
        args.out.mkdir(parents=True, exist_ok=True)
        progress = progress_bar() if args.progress else None
        with progress or nullcontext():
            for family in chosen:
                rows = measure(family, args.episodes, args.max_steps, progress)
                write_csv(args.out / f"{family.name}.csv", rows)
                cards.append(card(family, rows))
    (args.out / "README.md").write_text(
        "# Regime cards\n\nMade by `python -m experiments.regimes` from the CSV files beside this page "
        "(one row per rate, baseline and episode).\n[docs/scenario.md](../scenario.md#scenario-families) "
        f"describes the families.\n\n{NO_CARD}\n\n" + "\n".join(cards))
    print(f"wrote {len(chosen)} cards to {args.out / 'README.md'}")


if __name__ == "__main__":
    main()
