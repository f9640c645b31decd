"""The PettingZoo environment over the emulator: ``from env import ZenohEdgeEnv``."""

from env.environment import InvalidActionError, ZenohEdgeEnv
from env.reward import PaperWeights, RewardContext, RewardTerms

__all__ = ["InvalidActionError", "PaperWeights", "RewardContext", "RewardTerms", "ZenohEdgeEnv"]
