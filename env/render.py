"""Rendering of ``ZenohEdgeEnv``: a text table ("ansi") or a picture of the network ("rgb_array", "human").

The picture places nodes at their scenario positions; each is filled by its buffer occupancy (green to
red), ringed in red when overloaded, and the last step's offloads are arrows from the deciding node to
its target. pygame is imported lazily, so the environment itself does not need it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

SIZE = (900, 640)
MARGIN = 50
BACKGROUND = (250, 250, 247)


def occupancy_colour(fill: float) -> tuple[int, int, int]:
    """Green (empty) through amber to red (full)."""
    fill = min(max(fill, 0.0), 1.0)
    if fill < 0.5:
        return (int(80 + 350 * fill), 180, 90)
    return (235, int(180 - 260 * (fill - 0.5)), 70)


class Renderer:
    def __init__(self, env: Any) -> None:
        """``env``: the ZenohEdgeEnv to draw (its scenario, its simulation and its last actions)."""
        self.env = env
        self.sc = env.scenario
        self.screen = None
        self.pygame = None
        xs = [n.position[0] for n in self.sc.nodes]
        ys = [n.position[1] for n in self.sc.nodes]
        if max(xs) - min(xs) < 1e-9 and max(ys) - min(ys) < 1e-9:  # no positions: a circle
            k = len(self.sc.nodes)
            xs = [math.cos(2 * math.pi * i / k) for i in range(k)]
            ys = [math.sin(2 * math.pi * i / k) for i in range(k)]
        span_x, span_y = max(max(xs) - min(xs), 1e-9), max(max(ys) - min(ys), 1e-9)
        w, h = SIZE[0] - 2 * MARGIN, SIZE[1] - 2 * MARGIN - 40
        self.pos = {n.id: (MARGIN + (x - min(xs)) / span_x * w, MARGIN + 40 + (1 - (y - min(ys)) / span_y) * h)
                    for n, x, y in zip(self.sc.nodes, xs, ys, strict=True)}

    # ----- state of the network, from the last step -----

    def _nodes(self) -> dict[str, tuple[int, int, int, bool]]:
        """node -> (queue, occupancy, buffer, overloaded) as reported in the last tick."""
        from orchestrator.metrics import F

        metrics = self.env.sim.metrics
        if not metrics.n_ticks:
            return {}
        last = metrics.last_nodes
        out = {}
        for i, n in enumerate(self.sc.nodes):
            q, u = int(last[i, F["queue"]]), int(last[i, F["undecided"]])
            out[n.id] = (q, q + u, n.buffer, bool(last[i, F["overloaded"]]))
        return out

    def _offloads(self) -> list[tuple[str, str]]:
        moves = []
        for agent, action in self.env._last_actions.items():
            node = self.env.node_of[agent]
            for a in np.asarray(action).reshape(-1):
                if 0 < int(a) <= len(self.sc.neighbours[node]):
                    moves.append((node, self.sc.neighbours[node][int(a) - 1]))
        return moves

    # ----- modes -----

    def render(self, mode: str):
        if mode == "ansi":
            return self.text()
        surface = self.draw()
        if mode == "human":
            self.pygame.event.pump()
            self.screen.blit(surface, (0, 0))
            self.pygame.display.flip()
            return None
        return np.transpose(self.pygame.surfarray.array3d(surface), (1, 0, 2)).astype(np.uint8)

    def text(self) -> str:
        env = self.env
        nodes = self._nodes()
        moves = dict(self._offloads())
        lines = [f"{self.sc.name}  tick {env.sim.tick if env.sim else '-'}  step {env._steps}/{env.max_steps}",
                 f"{'node':<12}{'queue':>6}{'occ/buf':>10}  {'fill':<20}{'ovl':>4}  decision"]
        for n in self.sc.nodes:
            q, occ, buf, ovl = nodes.get(n.id, (0, 0, n.buffer, False))
            bar = "#" * round(20 * min(occ / buf, 1.0))
            decision = ""
            if n.has("controller") and f"ctrl_{n.id}" in env._last_actions:
                decision = f"-> {moves[n.id]}" if n.id in moves else "local"
            lines.append(f"{n.id:<12}{q:>6}{f'{occ}/{buf}':>10}  {bar:<20}{'!' if ovl else '':>4}  {decision}")
        return "\n".join(lines)

    def draw(self):
        if self.pygame is None:
            try:
                import pygame
            except ImportError:
                raise RuntimeError("rendering pictures needs pygame: pip install 'zenohedge[render]'") from None
            pygame.font.init()  # not pygame.init(): audio is never used, and its drivers complain on headless hosts
            self.pygame = pygame
            self.font = pygame.font.Font(None, 18)
            self.title_font = pygame.font.Font(None, 26)
            if self.env.render_mode == "human":
                pygame.display.init()
                self.screen = pygame.display.set_mode(SIZE)
                pygame.display.set_caption(f"ZenohEdge — {self.sc.name}")
        pg = self.pygame
        surf = pg.Surface(SIZE)
        surf.fill(BACKGROUND)
        drawn = set()
        for link in self.sc.links:
            key = frozenset((link.src, link.dst))
            if key in drawn:
                continue
            drawn.add(key)
            pg.draw.line(surf, (200, 200, 200), self.pos[link.src], self.pos[link.dst], 1)
        for src, dst in self._offloads():
            self._arrow(surf, self.pos[src], self.pos[dst])
        nodes = self._nodes()
        for n in self.sc.nodes:
            _, occ, buf, ovl = nodes.get(n.id, (0, 0, n.buffer, False))
            x, y = self.pos[n.id]
            radius = 9 + 3 * n.tier
            pg.draw.circle(surf, occupancy_colour(occ / buf), (int(x), int(y)), radius)
            pg.draw.circle(surf, (210, 30, 30) if ovl else (60, 60, 60), (int(x), int(y)), radius + 2, 3 if ovl else 1)
            label = self.font.render(f"{n.id} {occ}/{buf}", True, (30, 30, 30))
            surf.blit(label, (x - label.get_width() / 2, y + radius + 4))
        env = self.env
        title = (f"{self.sc.name}   tick {env.sim.tick if env.sim else 0}   step {env._steps}/{env.max_steps}   "
                 f"overloaded {sum(1 for v in nodes.values() if v[3])}")
        surf.blit(self.title_font.render(title, True, (20, 20, 20)), (MARGIN, 15))
        return surf

    def _arrow(self, surf, a: tuple[float, float], b: tuple[float, float]) -> None:
        pg = self.pygame
        colour = (40, 90, 200)
        pg.draw.line(surf, colour, a, b, 2)
        angle = math.atan2(b[1] - a[1], b[0] - a[0])
        tip = (b[0] - 14 * math.cos(angle), b[1] - 14 * math.sin(angle))
        left = (tip[0] - 8 * math.cos(angle - 0.5), tip[1] - 8 * math.sin(angle - 0.5))
        right = (tip[0] - 8 * math.cos(angle + 0.5), tip[1] - 8 * math.sin(angle + 0.5))
        pg.draw.polygon(surf, colour, [tip, left, right])

    def close(self) -> None:
        if self.pygame is not None:
            self.pygame.display.quit()
            self.pygame.quit()
            self.pygame = None
