"""Top-down picture of one frame around the ego, for backends without their own renderer (SUMO)."""

from __future__ import annotations

from typing import Any

import numpy as np

from simharness.sim.base import Frame


def render_frame(frame: Frame, road: Any, view: float = 40.0) -> np.ndarray:
    """(H, W, 3) uint8 image of `frame` within `view` m of the ego (matplotlib, off-screen)."""
    import matplotlib.pyplot as plt

    from simharness.report import draw_agents, draw_road

    fig, ax = plt.subplots(figsize=(6, 2.4), dpi=80)
    draw_road(ax, road)
    draw_agents(ax, frame.xy, frame.heading, frame.length, frame.width, frame.agent_type, ego=frame.ego)
    cx, cy = frame.xy[frame.ego] if frame.ego >= 0 else frame.xy.mean(0)
    ax.set_xlim(cx - view, cx + view)
    ax.set_ylim(cy - view * 0.4, cy + view * 0.4)
    ax.set_aspect("equal")
    ax.axis("off")
    fig.tight_layout(pad=0)
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return img
