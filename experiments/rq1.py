"""RQ1: one topology, varying task arrival rate lambda (the paper's Fig. "lambda variation", top row).

    python -m experiments.rq1 --quick --out runs/rq1-quick
    python -m experiments.rq1 --scenario aot2 --lambdas 0.05 0.1 0.17 0.25 0.35
"""

from __future__ import annotations

from collections.abc import Sequence

from experiments.common import rate
from experiments.sweep import Point, parser, run_study

LAMBDAS = (0.05, 0.1, 0.17, 0.25, 0.35)
QUICK_LAMBDAS = (0.1, 0.17, 0.25)


def main(argv: Sequence[str] | None = None) -> None:
    p = parser("rq1", "RQ1: how do the agents adapt to a fixed topology and varying task arrival rates?")
    p.add_argument("--scenario", default="aot2", help="topology (aot1..aot4 or a scenario YAML)")
    p.add_argument("--lambdas", type=rate, nargs="+", default=None,
                   help=f"arrival rates (default {' '.join(map(str, LAMBDAS))}; quick: "
                        f"{' '.join(map(str, QUICK_LAMBDAS))})")
    args = p.parse_args(argv)
    lambdas = args.lambdas or (QUICK_LAMBDAS if args.quick else LAMBDAS)
    points = [Point(f"{args.scenario}-lam{lam:g}", args.scenario, lam, lam) for lam in lambdas]
    run_study("rq1", points, "lambda", f"task arrival rate λ (tasks/s per source) on {args.scenario}", args)


if __name__ == "__main__":
    main()
