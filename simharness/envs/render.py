"""Top-down picture of one frame around the ego: the envs' `rgb_array` frames, one style for every backend.

Drawn with matplotlib off-screen (an Agg canvas, no display needed) in the project's style
(`simharness.style`): road grey with dashed markings, sidewalks light, each agent's box filled with its
type's colour, the ego black with an "ego" label, and a legend of the types in view.
"""

from __future__ import annotations

import numpy as np

from simharness.metrics.collisions import box_corners
from simharness.scene import AgentType
from simharness.sim.base import Frame, RoadGeometry
from simharness.style import EGO_COLOR, TYPE_COLORS, type_colors

WIDTH_PX, HEIGHT_PX = 720, 300  # the frame's size
VIEW = 40.0  # m shown ahead of and behind the ego


def render_frame(frame: Frame, road: RoadGeometry | None, view: float = VIEW, title: str | None = None
                 ) -> np.ndarray:
    """(HEIGHT_PX, WIDTH_PX, 3) uint8 image of `frame` within `view` m of the ego (the frame's centre without one)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    dpi = 100
    fig = Figure(figsize=(WIDTH_PX / dpi, HEIGHT_PX / dpi), dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.0, 1.0, 0.9 if title else 1.0))
    if road is not None:
        if road.sidewalks:
            ax.add_collection(PolyCollection(list(road.sidewalks), facecolor="#e6e6e6", edgecolor="none", zorder=0))
        if road.drivable:
            ax.add_collection(PolyCollection(list(road.drivable), facecolor="#bdbdbd", edgecolor="none", zorder=0))
        if road.markings:
            ax.add_collection(LineCollection(list(road.markings), colors="white", linewidths=0.8, linestyles="--",
                                             zorder=1))
    e = frame.ego
    cx, cy = frame.xy[e] if e >= 0 else (frame.xy.mean(0) if frame.num_agents else (0.0, 0.0))
    half_h = view * HEIGHT_PX / WIDTH_PX * (0.9 if title else 1.0)
    xy = frame.xy.astype(np.float64)
    seen = (np.abs(xy[:, 0] - cx) < view + 10) & (np.abs(xy[:, 1] - cy) < half_h + 10)
    if seen.any():
        heading = frame.extra.get("sim_heading", frame.heading)  # the bodies' headings (SUMO's differ)
        corners = box_corners(xy[seen], heading[seen].astype(np.float64), frame.length[seen].astype(np.float64),
                              frame.width[seen].astype(np.float64))
        colors = type_colors(frame.agent_type[seen])
        if e >= 0 and seen[e]:
            colors[int(np.count_nonzero(seen[:e]))] = EGO_COLOR
        ax.add_collection(PolyCollection(list(corners), facecolors=colors, edgecolors="black", linewidths=0.4,
                                         zorder=3))
    if e >= 0:
        ax.annotate("ego", (cx, cy), xytext=(0, 12), textcoords="offset points", ha="center", fontsize=9,
                    fontweight="bold", color=EGO_COLOR, zorder=5,
                    bbox={"boxstyle": "round,pad=0.15", "facecolor": "white", "edgecolor": "none", "alpha": 0.8})
    others = (np.abs(xy[:, 0] - cx) < view) & (np.abs(xy[:, 1] - cy) < half_h)  # the legend: types in view
    if e >= 0:
        others[e] = False
    present = sorted({int(t) for t in frame.agent_type[others]})
    handles = [Patch(facecolor=EGO_COLOR, label="ego")] if e >= 0 else []
    handles += [Patch(facecolor=TYPE_COLORS[AgentType(t)], label=AgentType(t).label) for t in present]
    if handles:
        ax.legend(handles=handles, loc="lower left", ncol=len(handles), fontsize=7, framealpha=0.85,
                  handlelength=1.0, columnspacing=0.8, borderpad=0.3)
    ax.set_xlim(cx - view, cx + view)
    ax.set_ylim(cy - half_h, cy + half_h)
    ax.set_aspect("equal")
    ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=9, y=0.98)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()
