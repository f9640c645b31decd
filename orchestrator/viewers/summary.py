"""An episode's summary.json as rows of text, read back through the metric catalogue.

The summary table of ``orchestrator launch`` and the numbers panel of ``orchestrator plot`` both show
these rows: every ``Out.TABLE`` metric in the summary's order, a metric with parts followed by one
indented row per part, values written by ``orchestrator.units.quantity``.
"""

from __future__ import annotations

from typing import Any

from orchestrator.catalogue import METRIC, Agg, Out, shown
from orchestrator.units import quantity

MISSING = object()


def at(summary: dict[str, Any], path: str) -> Any:
    """The value at a dotted path, or MISSING (a summary written before the metric existed)."""
    value: Any = summary
    for key in path.split("."):
        if not isinstance(value, dict) or key not in value:
            return MISSING
        value = value[key]
    return value


def rows(summary: dict[str, Any]) -> list[tuple[str, str]]:
    """(label, value) rows of the catalogue's TABLE metrics (the job metrics where the summary has jobs)."""
    out = []
    for m in shown(Out.TABLE, jobs="jobs" in summary):
        value = at(summary, m.key(Out.SUMMARY))
        if value is MISSING:
            continue
        if m.agg is Agg.SAMPLES:
            out.append((f"{m.label} mean / p50 / p95",
                        " / ".join(quantity(value.get(k), m.unit) for k in ("mean", "p50", "p95"))))
            continue
        whole = value.get("total") if isinstance(value, dict) else value
        text = quantity(whole, m.unit)
        base = at(summary, METRIC[m.share_of].key(Out.SUMMARY)) if m.share_of else MISSING
        if base is not MISSING and whole is not None:
            text += f"  ({100 * whole / max(base, 1):.1f} %)"
        out.append((f"{m.label} (mean)" if m.episode_mean else m.label, text))
        if isinstance(value, dict):
            out.extend((f"  {p.label}", quantity(value[p.key], m.unit)) for p in m.parts if p.key in value)
    return out


def policy_text(policy: str | list[str] | None) -> str:
    """summary.json's "policy" (one name when given for all controllers, else the scenario's, sorted)
    as "policy NAME" or "policies A, B"."""
    names = [policy] if isinstance(policy, str) else list(policy or [])
    if not names:
        return "no node-side policy (no controller)"
    return f"{'policy' if len(names) == 1 else 'policies'} {', '.join(names)}"

