"""Seeded random streams: one independent generator per node and role (docs/model.md, "Randomness and determinism").

Streams are keyed by the node's canonical index and a role number, never by process, so a
node draws the same numbers whatever process hosts it. Each role kind declares its number when it
registers (``RoleKind.stream``). Nothing in the emulator may use a global or unseeded generator.
"""

from __future__ import annotations

import numpy as np


def stream(seed: int, node_index: int, role: int, purpose: int = 0) -> np.random.Generator:
    seq = np.random.SeedSequence(seed, spawn_key=(node_index, role, purpose))
    return np.random.Generator(np.random.PCG64(seq))
