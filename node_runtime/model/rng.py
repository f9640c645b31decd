"""Seeded random streams: one independent generator per node and role (docs/model.md, "Randomness and determinism").

Streams are keyed by the node's canonical index and a role number, never by process, so a
node draws the same numbers whatever process hosts it. Each role kind declares its number when it
registers (``RoleKind.stream``). Nothing in the emulator may use a global or unseeded generator.
"""

from __future__ import annotations

import numpy as np

# A seed travels with every reset as a msgpack integer (64 bits at most), and a launch adds the episode to it
MAX_SEED = 2**62 - 1
# The role number of the streams of moving nodes' walks (``node_runtime.model.mobility``): no role kind takes it
MOBILITY = 2**31 - 1


def stream(seed: int, node_index: int, role: int, purpose: int = 0) -> np.random.Generator:
    seq = np.random.SeedSequence(seed, spawn_key=(node_index, role, purpose))
    return np.random.Generator(np.random.PCG64(seq))
