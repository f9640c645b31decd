"""The PettingZoo environment over the emulator: ``from env import ZenohEdgeEnv``."""

from env.actions import InvalidActionError
from env.batched import BatchedSteps
from env.credit import ArrayCredit
from env.environment import ZenohEdgeEnv
from env.observations import JobField, NeighbourField, OwnField, TaskField
from env.overrides import ScenarioOverrides
from env.reward import PaperWeights, RewardContext, RewardSettings, RewardTerms
from env.settings import MAX_SEED
from env.wrappers import InvalidActionPenalty, PotentialShaping
from node_runtime.model.array import Unsupported

__all__ = ["MAX_SEED", "ArrayCredit", "BatchedSteps", "InvalidActionError", "InvalidActionPenalty", "JobField",
           "NeighbourField", "OwnField", "PaperWeights", "PotentialShaping", "RewardContext", "RewardSettings",
           "RewardTerms", "ScenarioOverrides", "TaskField", "Unsupported", "ZenohEdgeEnv"]
