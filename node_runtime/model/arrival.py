"""Arrival-rate schedules λ(t), tasks per second per client: one class per ``kind`` of the scenario file.

Each kind answers the three questions the rest of the code asks of a schedule: the rate at a time of
the episode, the mean over the episode (what a worker expects to receive), and the peak (what the
scenario check holds to a bound). The scenario file's ``workload.arrival`` is validated as one of
these classes and used as it is by the node processes.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import Discriminator, Tag, model_validator

from node_runtime.model.values import NonNeg, Pos, Strict

Process = Literal["poisson", "exponential_gaps"]


class Schedule(Strict):
    """What every kind shares: the arrival process that draws tasks from the rate.

    ``poisson``: a Poisson count per tick. ``exponential_gaps``: one task at a time,
    max(1, ⌊Exp(λ) / dt⌋) ticks apart (the reference implementation's client)."""

    kind: str
    process: Process = "poisson"
    needs: ClassVar[tuple[str, ...]] = ()  # keys a file must give for this kind
    peak_keys: ClassVar[tuple[str, ...]] = ()  # the keys whose values bound the rate, for error messages

    @model_validator(mode="before")
    @classmethod
    def _keys_of_this_kind(cls, data: Any) -> Any:
        """A key of another kind, or a missing key, is named in one message with what this kind takes."""
        if not isinstance(data, dict):
            return data
        takes = set(cls.model_fields) - {"kind", "process"}
        kind = cls.model_fields["kind"].default
        stray = sorted(set(data) - takes - {"kind", "process"} - set(cls.unknown_keys(data)))
        if stray:
            raise ValueError(f"{', '.join(stray)} {'is' if len(stray) == 1 else 'are'} not used by kind "
                             f"{kind!r}, which takes {', '.join(sorted(takes))}")
        missing = [k for k in cls.needs if k not in data]
        if missing and not cls.unknown_keys(data):  # a misspelt key is named first, with its spelling hint
            raise ValueError(f"kind {kind!r} needs {', '.join(missing)}")
        return data

    @staticmethod
    def unknown_keys(data: dict[str, Any]) -> list[str]:
        """Keys no kind takes: left to the schema's 'unknown key' message (with its spelling hint)."""
        return [k for k in data if not any(k in c.model_fields for c in KINDS.values())]

    def rate_at(self, seconds: float, horizon: float) -> float:
        """λ at ``seconds`` into an episode of ``horizon`` seconds."""
        raise NotImplementedError

    @property
    def mean(self) -> float:
        """λ averaged over an episode (over clients, for a kind that draws a rate per client)."""
        raise NotImplementedError

    @property
    def peak(self) -> float:
        """The highest λ any client may use."""
        raise NotImplementedError

    def client_rate(self, rng: np.random.Generator) -> float | None:
        """A client's own constant rate, drawn at every reset, or None when the schedule gives it."""
        return None


class Constant(Schedule):
    kind: Literal["constant"] = "constant"
    peak_keys: ClassVar[tuple[str, ...]] = ("rate",)
    rate: NonNeg = 0.17

    def rate_at(self, seconds: float, horizon: float) -> float:
        return self.rate

    @property
    def mean(self) -> float:
        return self.rate

    @property
    def peak(self) -> float:
        return self.rate


class Linear(Schedule):
    """From ``start`` at the episode's first second to ``end`` at its last."""

    kind: Literal["linear"] = "linear"
    needs: ClassVar[tuple[str, ...]] = ("start", "end")
    peak_keys: ClassVar[tuple[str, ...]] = ("start", "end")
    start: NonNeg = 0.0
    end: NonNeg = 0.0

    def rate_at(self, seconds: float, horizon: float) -> float:
        frac = min(max(seconds / horizon, 0.0), 1.0) if horizon > 0 else 0.0
        return self.start + (self.end - self.start) * frac

    @property
    def mean(self) -> float:
        return (self.start + self.end) / 2

    @property
    def peak(self) -> float:
        return max(self.start, self.end)


class Ranged(Schedule):
    """A kind between ``low`` and ``high``."""

    low: NonNeg = 0.0
    high: NonNeg = 0.0
    peak_keys: ClassVar[tuple[str, ...]] = ("high",)

    @model_validator(mode="after")
    def _ordered(self) -> Ranged:
        if self.high < self.low:
            raise ValueError("high must be >= low")
        return self

    @property
    def mean(self) -> float:
        return (self.low + self.high) / 2

    @property
    def peak(self) -> float:
        return self.high


class Zigzag(Ranged):
    """A triangle wave: ``low`` at the start of every ``period`` seconds, ``high`` half-way through."""

    kind: Literal["zigzag"] = "zigzag"
    needs: ClassVar[tuple[str, ...]] = ("low", "high", "period")
    period: Pos = 100.0

    def rate_at(self, seconds: float, horizon: float) -> float:
        phase = (seconds % self.period) / self.period
        tri = 2 * phase if phase < 0.5 else 2 * (1 - phase)
        return self.low + (self.high - self.low) * tri


class Uniform(Ranged):
    """Each client draws a constant rate in [``low``, ``high``] at every reset."""

    kind: Literal["uniform"] = "uniform"
    needs: ClassVar[tuple[str, ...]] = ("low", "high")

    def rate_at(self, seconds: float, horizon: float) -> float:
        raise ValueError("a uniform schedule has no rate of its own: each client draws one (client_rate)")

    def client_rate(self, rng: np.random.Generator) -> float | None:
        return float(rng.uniform(self.low, self.high))


KIND_ERROR = "arrival_kind"  # the error type of a ``kind`` no class answers to
KINDS: dict[str, type[Schedule]] = {c.model_fields["kind"].default: c for c in (Constant, Linear, Zigzag, Uniform)}


def _kind_of(value: Any) -> str | None:
    if isinstance(value, dict):
        kind = value.get("kind", "constant")
        return f"<{kind}>" if isinstance(kind, str) else None
    return f"<{value.kind}>" if isinstance(value, Schedule) else None


# The file's ``workload.arrival``: the kind names the class (constant when it is left out). The tags are
# written <kind> so that an error's key path skips them (orchestrator.scenario.errors.key_path).
Arrival = Annotated[
    Annotated[Constant, Tag("<constant>")] | Annotated[Linear, Tag("<linear>")]
    | Annotated[Zigzag, Tag("<zigzag>")] | Annotated[Uniform, Tag("<uniform>")],
    Discriminator(_kind_of, custom_error_type=KIND_ERROR,
                  custom_error_message=f"expected a kind among {', '.join(map(repr, KINDS))}"),
]
