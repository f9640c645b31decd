"""The scenario file format (reference: docs/scenario.md).

The sections that are values of the model (``simulation``, ``workload.tasks``, ``workload.arrival``,
``failures``) are the model's own classes (``node_runtime.model.spec``, ``node_runtime.model.arrival``);
what only a file says (profiles, topology sources, the radio model, per-node overrides) is described
here. This pass checks structure only (types, ranges, required and unknown keys); meaning
(references between nodes, links, failures and traces; connectivity) is ``resolve``'s. Defaults
follow the paper's parameter table (λ = 0.17, α = 150 MiB, ρ = 8e7, ξ = 1, δ = 100 s, B = 2 MHz,
P = 20 dBm, 1000 steps).
"""

from __future__ import annotations

from functools import cache
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, create_model, field_validator, model_validator

from node_runtime.model.arrival import Arrival, Constant
from node_runtime.model.dag import JobSpec, LayeredDag
from node_runtime.model.mobility import MODEL_ERROR, GaussMarkov, RandomWaypoint, model_of
from node_runtime.model.spec import Failure, Hardware, SimulationSettings, TaskType, known_policy
from node_runtime.model.values import Decibels, NonNeg, Pos, Prob, Strict, optional
from node_runtime.runtime.keys import CHUNK
from topologies.generators import GENERATORS

# ----- the file format -----

class PathLossCfg(Strict):
    ref_loss_db: Decibels = 40.0
    ref_distance_m: Pos = 1.0
    exponent: Pos = 3.0
    frequency_hz: Pos | None = None  # instead of ref_loss_db: free-space loss at ref_distance_m

    @model_validator(mode="after")
    def one_reference(self) -> PathLossCfg:
        if self.frequency_hz is not None and "ref_loss_db" in self.model_fields_set:
            raise ValueError("give either ref_loss_db or frequency_hz (free-space loss at ref_distance_m), not both")
        return self


class NetworkCfg(Strict):
    bandwidth_hz: Pos = 2.0e6
    tx_power_dbm: Decibels = 20.0
    noise_dbm: Decibels | None = None  # default: thermal noise over the bandwidth, -174 + 10 log10(B) dBm
    path_loss: PathLossCfg = PathLossCfg()
    loss: Prob = 0.0
    range_m: Pos | None = None  # the radio range of moving nodes' links (needed when a node moves)
    on_break: Literal["drop", "retry"] = "drop"  # a transfer on a link that breaks: lost, or sent again


class TraceCfg(Strict):
    """``mobility: {model: trace, file: …}``: the node's rows of a CSV ``t,node,x,y`` (those of ``node``, by
    default the node's own id)."""

    model: Literal["trace"] = "trace"
    file: str
    node: str | None = None


class FcdCfg(Strict):
    """``mobility: {model: fcd, file: …}``: a vehicle of SUMO FCD output (``vehicle``, by default the node's id)."""

    model: Literal["fcd"] = "fcd"
    file: str
    vehicle: str | None = None


FILE_MODELS = ("random_waypoint", "gauss_markov", "trace", "fcd")
# A node's or profile's ``mobility``: the model names the class; a trace or FCD file is read when resolved.
MobilityCfg = Annotated[
    Annotated[RandomWaypoint, Tag("<random_waypoint>")] | Annotated[GaussMarkov, Tag("<gauss_markov>")]
    | Annotated[TraceCfg, Tag("<trace>")] | Annotated[FcdCfg, Tag("<fcd>")],
    Discriminator(model_of, custom_error_type=MODEL_ERROR,
                  custom_error_message=f"expected a model among {', '.join(map(repr, FILE_MODELS))}"),
]


class AlibabaJobsCfg(Strict):
    """``workload.jobs.alibaba``: the DAGs of the jobs of an Alibaba v2018 ``batch_task.csv``
    (``topologies.alibaba_dag``; each value as ``topologies.alibaba.Conversion`` documents it)."""

    file: str
    limit: Annotated[int, Field(ge=1)] | None = None  # the earliest jobs only
    frequency: Pos = 4.0e6
    memory_bytes: Pos = 1.0e9
    output_ratio: Pos = 1.0
    deadline_factor: Pos = 3.0
    min_deadline: Pos = 10.0
    time_scale: Pos = 1.0
    cpi: Pos = 1.0


class JobsCfg(Strict):
    """``workload.jobs``: every arrival is a job, a DAG of tasks: one of ``dags`` (drawn by weight), of the
    DAGs imported from ``alibaba``, or drawn by ``generator``."""

    dags: list[JobSpec] | None = None
    generator: LayeredDag | None = None
    alibaba: AlibabaJobsCfg | None = None

    @model_validator(mode="after")
    def one_source(self) -> JobsCfg:
        given = [k for k in ("dags", "generator", "alibaba") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"expected exactly one of dags, generator, alibaba (got {', '.join(given) or 'none'})")
        if self.dags is not None and not self.dags:
            raise ValueError("dags: expected at least one job")
        return self


class WorkloadCfg(Strict):
    arrival: Arrival = Constant()
    rates: dict[str, NonNeg] = Field(default_factory=dict)
    targets: dict[str, list[str]] = Field(default_factory=dict)
    tasks: Annotated[list[TaskType], Field(min_length=1)] = Field(default_factory=lambda: [TaskType()])
    trace: str | None = None
    source: str | None = None  # import path of a TaskSource subclass
    jobs: JobsCfg | None = None  # every arrival is a job (a DAG of tasks) rather than a task of ``tasks``

    @model_validator(mode="after")
    def one_workload(self) -> WorkloadCfg:
        if self.jobs is not None and (self.trace is not None or self.source is not None):
            raise ValueError("jobs come from the arrival process: remove trace and source, or jobs")
        if self.trace is not None:
            ignored = sorted({"arrival", "rates", "source"} & self.model_fields_set)
            if ignored:
                raise ValueError(f"a trace gives every task itself: remove {', '.join(ignored)} "
                                 "(task sizes come from the trace too; 'tasks' only sizes Ether buffers)")
        return self


class EnergyCfg(Strict):
    kappa: NonNeg = 1.0e-27
    idle_power_w: NonNeg = 0.0


class RolesCfg(Strict):
    """User subclasses of the roles, by import path ("package.module:Class"): a key per role kind
    (``file_format`` adds them)."""


# A profile's or a node entry's hardware: any of a resolved node's, with the same types and ranges
HardwareCfg: Any = create_model("HardwareCfg", __base__=Strict, **optional(Hardware))


class ProfileCfg(HardwareCfg):
    """Hardware (any of a node's, ``Hardware``) and roles of a node. ``file_format`` adds ``<kind>: bool``
    per role kind (whether the node has that role)."""

    policy: str | None = None
    roles: RolesCfg | None = None
    params: dict[str, float | int | bool | str] | None = None  # free parameters for user extensions
    mobility: MobilityCfg | None = None  # how the node moves (docs/scenario.md, "Moving nodes")

    @field_validator("policy")
    @classmethod
    def _known_policy(cls, v: str | None) -> str | None:
        return None if v is None else known_policy(v)


class NodeCfg(ProfileCfg):
    id: str
    profile: str | None = None
    position: tuple[float, float] = (0.0, 0.0)

    @field_validator("id")
    @classmethod
    def chunk(cls, v: str) -> str:
        if not CHUNK.match(v):
            raise ValueError("expected a name of letters, digits, '_', '.' or '-'")
        return v


class LinkCfg(Strict):
    between: tuple[str, str]
    rate_bps: Pos | None = None
    gain_db: Decibels | None = None
    loss: Prob | None = None

    @model_validator(mode="before")
    @classmethod
    def pair(cls, v: Any) -> Any:
        return {"between": v} if isinstance(v, (list, tuple)) else v


class GeneratorCfg(BaseModel):
    model_config = ConfigDict(extra="allow", frozen=True)
    kind: str

    @field_validator("kind")
    @classmethod
    def known(cls, v: str) -> str:
        if v not in GENERATORS:
            raise ValueError(f"expected one of {', '.join(GENERATORS)}")
        return v


class TopologyCfg(Strict):
    ether: str | None = None
    link_rates: Literal["wireless", "ether"] = "wireless"
    buffer_bytes: Pos | None = None  # Ether buffers: round(memory / buffer_bytes) instead of memory / task size
    generator: GeneratorCfg | None = None
    nodes: list[NodeCfg] = Field(default_factory=list)
    links: list[LinkCfg] = Field(default_factory=list)

    @model_validator(mode="after")
    def one_source(self) -> TopologyCfg:
        sources = [s for s in ("ether", "generator") if getattr(self, s) is not None]
        if len(sources) > 1:
            raise ValueError("give either 'ether' or 'generator', not both")
        for key in ("link_rates", "buffer_bytes"):
            if key in self.model_fields_set and self.ether is None:
                raise ValueError(f"{key} only applies to an Ether import ('ether: FILE')")
        if not sources and not self.nodes:
            raise ValueError("expected one of 'ether', 'generator' or 'nodes'")
        return self


# the environment's built-in rewards (env.reward.REWARDS)
REWARD_NAMES = ("paper", "reference", "sparse", "team", "score", "team_score", "marginal")


class ScenarioFile(Strict):
    name: str | None = None
    description: str = ""
    roles: RolesCfg = RolesCfg()
    reward: str | None = None  # for the environment: one of REWARD_NAMES, or an import path of a callable
    observation: str | None = None  # for the environment: import path of an observation builder class
    simulation: SimulationSettings = SimulationSettings()
    network: NetworkCfg = NetworkCfg()
    workload: WorkloadCfg = WorkloadCfg()
    energy: EnergyCfg = EnergyCfg()
    profiles: dict[str, ProfileCfg] = Field(default_factory=dict)
    topology: TopologyCfg
    failures: list[Failure] = Field(default_factory=list)


@cache
def file_format(kinds: tuple[str, ...]) -> type[ScenarioFile]:
    """The file format for these role kinds (node_runtime.model.registry): ``<kind>: bool`` on
    profiles and nodes, and ``<kind>: import path`` under every ``roles``."""
    roles: Any = create_model("RolesCfg", __base__=RolesCfg, **{k: (str | None, None) for k in kinds})
    flags: dict[str, Any] = {k: (bool | None, None) for k in kinds}
    profile: Any = create_model("ProfileCfg", __base__=ProfileCfg, roles=(roles | None, None), **flags)
    node: Any = create_model("NodeCfg", __base__=NodeCfg, roles=(roles | None, None), **flags)
    topology: Any = create_model("TopologyCfg", __base__=TopologyCfg, nodes=(list[node], []))
    return create_model("ScenarioFile", __base__=ScenarioFile, roles=(roles, roles()),
                        profiles=(dict[str, profile], {}), topology=(topology, ...))


# Built-in hardware profiles: the AoT devices (Ether data, reference mapping) and the paper's tiers.
BUILTIN_PROFILES: dict[str, dict[str, Any]] = {
    "rpi3": {"cores": 1, "frequency": 4.0e6, "buffer": 3, "tier": 0, "controller": True, "client": True},
    "tx2": {"cores": 1, "frequency": 4.0e6, "buffer": 26, "tier": 1},
    "nuc": {"cores": 1, "frequency": 3.2e7, "buffer": 54, "tier": 1, "controller": True},
    "server": {"cores": 1, "frequency": 8.8e7, "buffer": 597, "tier": 2, "controller": True},
    "tier0": {"cores": 1, "frequency": 4.0e7, "buffer": 20, "tier": 0, "controller": True, "client": True},
    "tier1": {"cores": 1, "frequency": 2.0e7, "buffer": 10, "tier": 1, "controller": True},
    "tier2": {"cores": 2, "frequency": 8.0e7, "buffer": 100, "tier": 2, "controller": True},
}
NODE_DEFAULTS: dict[str, Any] = {"cores": 1, "frequency": 4.0e7, "buffer": 20, "tier": 0}  # roles: RoleKind.default


