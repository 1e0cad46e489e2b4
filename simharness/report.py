"""Figures (matplotlib, headless), animations and report pages.

Shared drawing pieces live at the top (colours by type, road, footprints,
trails); each figure is one function that takes arrays or a Scene and writes
a file. Other modules add their figures here, one function each.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless everywhere; no display on CI
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from simharness.metrics.collisions import box_corners  # noqa: E402
from simharness.scene import AgentType, Scene  # noqa: E402
from simharness.sim.base import RoadGeometry  # noqa: E402

TYPE_COLORS: dict[AgentType, str] = {
    AgentType.CAR: "#1f77b4",
    AgentType.BUS: "#d62728",
    AgentType.TRUCK: "#8c564b",
    AgentType.RICKSHAW: "#2ca02c",
    AgentType.MOTORCYCLE: "#ff7f0e",
    AgentType.SCOOTER: "#e377c2",
    AgentType.BICYCLE: "#17becf",
    AgentType.PEDESTRIAN: "#9467bd",
    AgentType.OTHER: "#7f7f7f",
}
EGO_COLOR = "#000000"


def type_colors(agent_type: np.ndarray) -> list[str]:
    """(N,) int8 -> N colour strings."""
    return [TYPE_COLORS[AgentType(int(t))] for t in agent_type]


def draw_road(ax: Axes, road: RoadGeometry | None) -> None:
    """Carriageways grey, sidewalks light, markings dashed white."""
    if road is None:
        return
    if road.sidewalks:
        ax.add_collection(PolyCollection(list(road.sidewalks), facecolor="#e6e6e6", edgecolor="none", zorder=0))
    if road.drivable:
        ax.add_collection(PolyCollection(list(road.drivable), facecolor="#bdbdbd", edgecolor="none", zorder=0))
    if road.markings:
        ax.add_collection(LineCollection(list(road.markings), colors="white", linewidths=0.8,
                                         linestyles="--", zorder=1))


def draw_agents(ax: Axes, xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray,
                agent_type: np.ndarray, ego: int = -1, highlight: np.ndarray | None = None) -> None:
    """Footprints of n agents at one instant: xy (n, 2), heading/length/width/agent_type (n,).

    highlight: optional (n,) bool drawn with a red edge (e.g. colliding agents).
    """
    if len(xy) == 0:
        return
    corners = box_corners(xy, heading, length, width)
    colors = type_colors(agent_type)
    if 0 <= ego < len(colors):
        colors[ego] = EGO_COLOR
    edges = np.where(highlight, "red", "black") if highlight is not None else "black"
    ax.add_collection(PolyCollection(list(corners), facecolors=colors, edgecolors=edges,
                                     linewidths=0.4 if highlight is None else 1.2, zorder=3))


def draw_trails(ax: Axes, scene: Scene, frame: int, seconds: float = 3.0) -> None:
    """Each agent's last `seconds` of positions up to `frame`, coloured by type."""
    start = max(0, frame - int(round(seconds / scene.dt)))
    segs, cols = [], []
    for i in np.flatnonzero(scene.valid[:, frame]):  # drawing only, not a hot path
        pts = scene.xy[i, start:frame + 1][scene.valid[i, start:frame + 1]]
        if len(pts) > 1:
            segs.append(pts)
            cols.append(EGO_COLOR if i == scene.ego else TYPE_COLORS[AgentType(int(scene.agent_type[i]))])
    ax.add_collection(LineCollection(segs, colors=cols, linewidths=0.8, alpha=0.6, zorder=2))


def type_legend(ax: Axes, types: np.ndarray | None = None, ego: bool = False) -> None:
    """Legend of the agent types present (all if None)."""
    present = sorted({int(t) for t in types}) if types is not None else [int(t) for t in AgentType]
    handles = [Patch(color=TYPE_COLORS[AgentType(t)], label=AgentType(t).label) for t in present]
    if ego:
        handles.append(Patch(color=EGO_COLOR, label="ego"))
    ax.legend(handles=handles, loc="upper right", fontsize=7, ncol=min(len(handles), 5), framealpha=0.8)


def plot_frame(scene: Scene, frame: int, path: Path | str, road: RoadGeometry | None = None,
               trail_s: float = 3.0, title: str | None = None) -> Path:
    """One frame top-down: road, every footprint coloured by type, last `trail_s` of trails -> PNG."""
    path = Path(path)
    valid = scene.valid[:, frame]
    pts = scene.xy[valid, frame]
    fig, ax = plt.subplots(figsize=(12, 4.5), dpi=120)
    draw_road(ax, road)
    draw_trails(ax, scene, frame, trail_s)
    draw_agents(ax, pts, scene.heading[valid, frame], scene.length[valid], scene.width[valid],
                scene.agent_type[valid], ego=int(np.flatnonzero(np.flatnonzero(valid) == scene.ego)[0])
                if scene.ego >= 0 and valid[scene.ego] else -1)
    if road is not None and road.drivable:
        x0, y0, x1, y1 = road.bounds()
    elif len(pts):
        (x0, y0), (x1, y1) = pts.min(0) - 5, pts.max(0) + 5
    else:
        x0, y0, x1, y1 = 0, 0, 1, 1
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel(f"x ({scene.units})")
    ax.set_ylabel(f"y ({scene.units})")
    ax.set_title(title or f"{scene.meta.get('scenario', '')} t = {scene.times[frame]:.1f} s, "
                          f"{int(valid.sum())} agents")
    type_legend(ax, scene.agent_type[valid], ego=scene.ego >= 0)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
