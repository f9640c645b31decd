"""A small image classifier, the payload of ``payload_classifier.yaml``: real numpy work in the loop.

Each call classifies a batch of synthetic 28 x 28 grey images, generated from the task's id, with a fixed
random-weight network: eight 3 x 3 convolutions, ReLU, 2 x 2 max pooling, a 64-unit dense layer and ten
classes. The weights are not trained (the labels mean nothing); what matters is that the CPU work is
real and of a known shape: it grows linearly with ``batch``.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

SIDE, FILTERS, HIDDEN, CLASSES = 28, 8, 64, 10


@cache
def weights() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The network's fixed weights, drawn once per process from a seed of their own."""
    rng = np.random.default_rng(2024)
    pooled = FILTERS * ((SIDE - 2) // 2) ** 2
    return (rng.standard_normal((FILTERS, 3, 3)).astype(np.float32) / 3,
            rng.standard_normal((pooled, HIDDEN)).astype(np.float32) / np.sqrt(pooled),
            rng.standard_normal((HIDDEN, CLASSES)).astype(np.float32) / np.sqrt(HIDDEN))


def classify(task_id: int, batch: int = 16) -> np.ndarray:
    """The predicted class of each of ``batch`` images generated for task ``task_id``."""
    conv, dense, out = weights()
    images = np.random.default_rng(task_id).random((batch, SIDE, SIDE), dtype=np.float32)
    patches = sliding_window_view(images, (3, 3), axis=(1, 2))  # batch x 26 x 26 x 3 x 3
    maps = np.maximum(np.einsum("bijkl,fkl->bfij", patches, conv), 0.0)  # batch x 8 x 26 x 26
    side = (SIDE - 2) // 2
    pooled = maps.reshape(batch, FILTERS, side, 2, side, 2).max(axis=(3, 5)).reshape(batch, -1)
    hidden = np.maximum(pooled @ dense, 0.0)
    return np.argmax(hidden @ out, axis=1)
