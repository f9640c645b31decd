"""The checked value types every part of the scenario model is built from.

A scenario is validated once, where it enters (a file, a dict from the bus), and then used as it is:
these are the constraints that validation applies, named once for every section that uses them.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field

Pos = Annotated[float, Field(gt=0)]
NonNeg = Annotated[float, Field(ge=0)]
Prob = Annotated[float, Field(ge=0, le=1)]
Count = Annotated[int, Field(ge=1)]
Tick = Annotated[int, Field(ge=0)]
# Levels in dB or dBm: their power form 10^(x/10) must be a float (below 1.8e308)
DB_LIMIT = 3000.0
Decibels = Annotated[float, Field(ge=-DB_LIMIT, le=DB_LIMIT)]


class Strict(BaseModel):
    """Unknown keys refused, values frozen once validated. inf and nan are no quantity of the model:
    refused rather than left to turn results into nan."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def optional(model: type[BaseModel]) -> dict[str, Any]:
    """``model``'s fields, each optional (None when not given) with the same type and constraints: for a
    section of a file that may give any of them (a hardware profile gives some of a node's hardware)."""
    fields = model.model_fields.items()
    return {name: ((Annotated[info.annotation, *info.metadata] if info.metadata else info.annotation) | None, None)
            for name, info in fields}
