"""RQ2: fixed arrival rate, growing network: AoT with 1 to 4 clusters (the paper's figure, bottom row).

    python -m experiments.rq2 --quick --out runs/rq2-quick
    python -m experiments.rq2 --scenarios aot1 aot2 aot3 aot4 --lam 0.17
    python -m experiments.rq2 --scenarios aot1_urgent aot2_urgent aot3_urgent aot4_urgent --lam 0.04 --reward marginal
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from experiments.common import rate
from experiments.sweep import Point, parser, run_study

SCENARIOS = ("aot1", "aot2", "aot3", "aot4")
QUICK_SCENARIOS = ("aot1", "aot2", "aot4")


def clusters(scenario: str) -> float | None:
    """aotN and its variants (aotN_urgent, ...) have N clusters; other scenarios are placed by their position in
    the list."""
    m = re.fullmatch(r"aot(\d+)(?:_\w+)?", scenario)
    return float(m.group(1)) if m else None


def main(argv: Sequence[str] | None = None) -> None:
    p = parser("rq2", "RQ2: how do the agents adapt to a fixed arrival rate and more nodes and agents?")
    p.add_argument("--scenarios", nargs="+", default=None,
                   help=f"topologies in order (default {' '.join(SCENARIOS)}; quick: {' '.join(QUICK_SCENARIOS)})")
    p.add_argument("--lam", type=rate, default=0.17, help="task arrival rate lambda per source (default 0.17)")
    args = p.parse_args(argv)
    scenarios = args.scenarios or (QUICK_SCENARIOS if args.quick else SCENARIOS)
    xs = [clusters(s) or float(i + 1) for i, s in enumerate(scenarios)]
    points = [Point(f"{s}-lam{args.lam:g}", s, args.lam, x) for s, x in zip(scenarios, xs, strict=True)]
    labels = {x: (f"{x:g}" if clusters(s) else s) for s, x in zip(scenarios, xs, strict=True)}
    run_study("rq2", points, "clusters", f"number of AoT clusters (λ = {args.lam:g})", args, labels)


if __name__ == "__main__":
    main()
