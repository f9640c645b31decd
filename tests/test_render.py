"""Pictures of the environment render on a headless host without noise from unused pygame modules."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytest.importorskip("pygame")

SCRIPT = """
from env import ZenohEdgeEnv
env = ZenohEdgeEnv("aot1", transport="inproc", render_mode="rgb_array")
env.reset(seed=0)
frame = env.render()
env.close()
print(frame.shape, frame.dtype)
"""


def test_rgb_array_on_a_headless_host_prints_nothing_but_the_frame():
    environ = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "XDG_RUNTIME_DIR")}
    environ["PYGAME_HIDE_SUPPORT_PROMPT"] = "1"
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=environ, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "(640, 900, 3) uint8"
    assert proc.stderr == ""
