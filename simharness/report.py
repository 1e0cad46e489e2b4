"""Figures (matplotlib, headless), animations and report pages.

Shared drawing pieces live at the top (colours by type, road, footprints,
trails); each figure is one function that takes arrays or a Scene and writes
a file. Other modules add their figures here, one function each.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless everywhere; no display on CI
matplotlib.rcParams["savefig.bbox"] = "tight"  # keep legends placed outside the axes
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.artist import Artist  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from simharness.io.parquet import atomic_write_bytes  # noqa: E402
from simharness.metrics.collisions import box_corners, box_heading  # noqa: E402
from simharness.scene import AgentType, Scene  # noqa: E402
from simharness.sim.base import RoadGeometry  # noqa: E402
from simharness.style import EGO_COLOR, TYPE_COLORS, type_colors  # noqa: E402


def _save(fig: plt.Figure, path: Path) -> Path:
    """Lay out, write atomically (creating folders) and close a figure; returns its path."""
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format=path.suffix.lstrip(".") or "png")
    plt.close(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buf.getvalue())  # a figure is never seen half-written either
    return path


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


def type_legend(ax: Axes, types: np.ndarray | None = None, ego: bool = False, extra: Sequence[Artist] = (),
                ncol: int = 1) -> None:
    """Legend of the agent types present (all if None), the ego if drawn, then `extra` handles (lines etc.)."""
    present = sorted({int(t) for t in types}) if types is not None else [int(t) for t in AgentType]
    handles = [Patch(color=TYPE_COLORS[AgentType(t)], label=AgentType(t).label) for t in present]
    if ego:
        handles.append(Patch(color=EGO_COLOR, label="ego"))
    # Outside the axes, to the right: over the road it hid agents.
    ax.legend(handles=[*handles, *extra], loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, framealpha=0.8,
              ncol=ncol)


def label_ego(ax: Axes, xy: np.ndarray) -> None:
    """Write "ego" above the ego's footprint at xy (2,) metres, so that it is found at a glance."""
    ax.annotate("ego", xy=(float(xy[0]), float(xy[1])), xytext=(0, 14), textcoords="offset points", ha="center",
                fontsize=8, fontweight="bold", color="white", zorder=7,
                bbox={"boxstyle": "round,pad=0.2", "facecolor": EGO_COLOR, "edgecolor": "none"},
                arrowprops={"arrowstyle": "-", "color": EGO_COLOR, "lw": 1.0})


def ego_window(ego_xy: np.ndarray, road: RoadGeometry | None, behind: float = 20.0, ahead: float = 45.0,
               margin: float = 1.0) -> tuple[float, float, float, float]:
    """(xmin, ymin, xmax, ymax) metres of a view that follows the ego at ego_xy (2,): `behind` and `ahead` of it
    along x, and across the road's whole width (its bounds plus `margin`), so no half of the frame is empty;
    without a road, 8 m either side of the ego."""
    cx, cy = float(ego_xy[0]), float(ego_xy[1])
    if road is not None and (road.drivable or road.sidewalks):
        _, y0, _, y1 = road.bounds()
        y0, y1 = min(y0, cy - 3.0) - margin, max(y1, cy + 3.0) + margin  # an ego off the road stays in view
    else:
        y0, y1 = cy - 8.0, cy + 8.0
    return cx - behind, y0, cx + ahead, y1


def plot_frame(scene: Scene, frame: int, path: Path | str, road: RoadGeometry | None = None,
               trail_s: float = 3.0, title: str | None = None,
               window: tuple[float, float, float, float] | None = None) -> Path:
    """One frame top-down: road, every footprint coloured by type, last `trail_s` of trails -> PNG.

    window: optional (xmin, ymin, xmax, ymax) metres to show (default: the road's bounds).
    """
    path = Path(path)
    valid = scene.valid[:, frame]
    pts = scene.xy[valid, frame]
    fig, ax = plt.subplots(figsize=(12, 4.5), dpi=120)
    draw_road(ax, road)
    draw_trails(ax, scene, frame, trail_s)
    draw_agents(ax, pts, box_heading(scene)[valid, frame], scene.length[valid], scene.width[valid],
                scene.agent_type[valid], ego=int(np.flatnonzero(np.flatnonzero(valid) == scene.ego)[0])
                if scene.ego >= 0 and valid[scene.ego] else -1)
    if window is not None:
        x0, y0, x1, y1 = window
    elif road is not None and road.drivable:
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
    has_ego = 0 <= scene.ego and bool(valid[scene.ego])
    if has_ego:
        label_ego(ax, scene.xy[scene.ego, frame])
    type_legend(ax, scene.agent_type[valid], ego=has_ego)
    return _save(fig, path)


# ---------------------------------------------------------------------- closed loop (simharness.closedloop)
def animate_episode(scene: Scene, path: Path | str, road: RoadGeometry | None = None,
                    forecast_frames: list[int] | None = None, forecasts: list | None = None,
                    behind: float = 20.0, ahead: float = 45.0, max_frames: int = 150, fps: int = 5) -> Path:
    """GIF of a closed-loop episode following the ego: traffic by type, the ego black and labelled, its latest
    forecast of the others (lines, 1-sigma end circles), agents touching the ego edged red; axes in metres and
    a legend beside the road.

    scene: the recorded episode (ego row set); forecast_frames/forecasts: frame index and `Forecast` of
    each prediction; behind/ahead: metres of road shown behind and ahead of the ego (the view spans the
    road's width across).
    """
    import imageio.v2 as imageio
    from matplotlib.patches import Circle

    from simharness.metrics.safety import ego_contact

    path = Path(path)
    e = scene.ego
    frames = np.flatnonzero(scene.valid[e]) if e >= 0 else np.arange(scene.num_frames)
    frames = frames[:: max(1, int(np.ceil(len(frames) / max_frames)))]
    body = box_heading(scene)  # the bodies' heading, as scored (SUMO's boxes stay lane-aligned)
    contact = ego_contact(scene.xy, body, scene.length, scene.width, scene.valid, e) if e >= 0 else None
    issued = np.asarray(forecast_frames or [], int)

    def centre(f: int) -> np.ndarray:
        return scene.xy[e, f] if e >= 0 else scene.xy[scene.valid[:, f], f].mean(0)

    x0, y0, x1, y1 = ego_window(centre(frames[0]), road, behind, ahead)
    # size the figure to the window's shape (+ room for the legend), so the road fills the frame
    width = 7.5
    fig, ax = plt.subplots(figsize=(width + 3.0, max(2.2, width * (y1 - y0) / (x1 - x0) + 0.8)), dpi=100)
    extra = [Line2D([], [], color="#444444", lw=0.9, label="forecast (mean)"),
             Line2D([], [], color="#444444", lw=0, marker="o", markerfacecolor="none", label="forecast 1-sigma at 5 s"),
             Patch(facecolor="white", edgecolor="red", lw=1.2, label="touching the ego")]
    types = scene.agent_type[scene.valid[:, frames].any(1)]
    images = []
    for f in frames:  # one image per frame; agents drawn vectorised inside
        ax.clear()
        draw_road(ax, road)
        draw_trails(ax, scene, int(f), 2.0)
        valid = scene.valid[:, f]
        rows = np.flatnonzero(valid)
        hit = contact[rows, f] if contact is not None else None
        if hit is not None and e in rows:
            hit = hit.copy()
            hit[rows == e] = contact[:, f].any()
        draw_agents(ax, scene.xy[rows, f], body[rows, f], scene.length[rows], scene.width[rows],
                    scene.agent_type[rows], ego=int(np.flatnonzero(rows == e)[0]) if e in rows else -1, highlight=hit)
        k = np.searchsorted(issued, f, side="right") - 1
        if forecasts and k >= 0:
            fc = forecasts[k]
            ax.add_collection(LineCollection(list(fc.mean), colors="#444444", linewidths=0.7, alpha=0.7, zorder=4))
            if fc.sigma_rho is not None:
                for m in range(len(fc.agent_id)):  # drawing only
                    ax.add_patch(Circle(fc.mean[m, -1], float(fc.sigma_rho[m, -1, :2].mean()), fill=False,
                                        edgecolor="#444444", linewidth=0.4, alpha=0.5, zorder=4))
        x0, y0, x1, y1 = ego_window(centre(f), road, behind, ahead)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        if e in rows:
            label_ego(ax, scene.xy[e, f])
        ax.set_xlabel(f"x ({scene.units})", fontsize=8)
        ax.set_ylabel(f"y ({scene.units})", fontsize=8)
        ax.tick_params(labelsize=7)
        type_legend(ax, types, ego=e >= 0, extra=extra, ncol=2)
        collided = contact is not None and contact[:, : f + 1].any()
        ax.set_title(f"ego on {scene.meta.get('predictor', '')} forecasts, seed {scene.meta.get('seed', '')}, "
                     f"t = {scene.times[f]:.1f} s, ego speed {scene.speed[e, f]:.1f} m/s"
                     + ("  COLLISION" if collided else ""), fontsize=8, color="red" if collided else "black")
        fig.tight_layout()
        fig.canvas.draw()
        images.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    plt.close(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(".tmp-" + path.name)
    imageio.mimsave(tmp, images, duration=1.0 / fps, loop=0)
    tmp.replace(path)
    return path


SCORECARD_PANELS = (("composite", "composite score", "score (0-1, higher is better)"),
                    ("collision_rate", "collision rate", "share of episodes"),
                    ("at_fault_collision_rate", "at-fault collision rate", "share of episodes"),
                    ("progress_m", "progress", "distance along the road (m)"),
                    ("online_ade", "online prediction error", "ADE (m, mean Euclidean)"))


def panel_ylim(key: str, hi: np.ndarray) -> tuple[float, float] | None:
    """The y range of a scorecard panel: shares and the composite on their whole 0-1 scale (a panel of zeros
    then reads as zero, not as a band around it); others from 0 to 10% above the highest CI end (hi, (N,))."""
    if key == "composite" or key.endswith("_rate"):
        return 0.0, 1.0
    top = float(np.nanmax(hi)) if np.isfinite(hi).any() else 0.0
    return (0.0, 1.1 * top) if top > 0 else (0.0, 1.0)


def plot_scorecard(scores: dict[str, dict], path: Path | str) -> Path:
    """Bars with 95% CIs per ego: composite score, collision rates, progress, online ADE -> PNG.

    scores: ego name -> `simharness.closedloop.aggregate` output. Each bar is labelled with its mean.
    """
    path = Path(path)
    names = list(scores)
    colors = [plt.get_cmap("tab10")(i % 10) for i in range(len(names))]  # one colour per ego, in every panel
    fig, axes = plt.subplots(1, len(SCORECARD_PANELS), figsize=(3.2 * len(SCORECARD_PANELS), 3.4), dpi=110)
    for ax, (key, title, ylabel) in zip(axes, SCORECARD_PANELS, strict=True):
        ci = [scores[n].get(key, {}) for n in names]  # scores.json written before a key existed lack it
        mean = np.array([c.get("mean", np.nan) for c in ci], float)
        lo = np.array([c.get("lo", np.nan) for c in ci], float)
        hi = np.array([c.get("hi", np.nan) for c in ci], float)
        x = np.arange(len(names))
        ok = np.isfinite(mean)
        ax.bar(x[ok], mean[ok], color=[colors[i] for i in np.flatnonzero(ok)])
        ax.errorbar(x[ok], mean[ok], yerr=[mean[ok] - lo[ok], hi[ok] - mean[ok]], fmt="none", ecolor="black",
                    capsize=3)
        ylim = panel_ylim(key, np.where(np.isfinite(hi), hi, mean))
        ax.set_ylim(*ylim)
        for i in x:  # the mean written on each bar; "n/a" where the ego has no such figure (no forecasts)
            label = f"{mean[i]:.2f}" if ok[i] else "n/a"
            top = hi[i] if ok[i] and np.isfinite(hi[i]) else (mean[i] if ok[i] else 0.0)
            ax.text(i, top + 0.02 * ylim[1], label, ha="center", va="bottom", fontsize=7)
        ax.set_xticks(x, names, rotation=30, fontsize=8)
        ax.set_xlabel("ego's forecasts", fontsize=8)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.set_title(title, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle("closed loop: mean over episodes, bars 95% bootstrap CI", fontsize=9)
    return _save(fig, path)


def plot_online_error_by_type(scores: dict[str, dict], path: Path | str) -> Path:
    """Online ADE (mean Euclidean, m) per agent type, one bar group per type, one bar per ego -> PNG."""
    path = Path(path)
    names = [n for n in scores if scores[n].get("online_by_type")]
    types = [t.label for t in AgentType if any(t.label in scores[n]["online_by_type"] for n in names)]
    fig, ax = plt.subplots(figsize=(8, 3.4), dpi=110)
    width = 0.8 / max(len(names), 1)
    for i, n in enumerate(names):
        vals = [scores[n]["online_by_type"].get(t, {}).get("ade", {}).get("mean", np.nan) for t in types]
        ax.bar(np.arange(len(types)) + i * width, vals, width, label=n)
    ax.set_xticks(np.arange(len(types)) + 0.4 - width / 2, types, fontsize=8)
    ax.set_xlabel("type of the agent forecast")
    ax.set_ylabel("online ADE (m, mean Euclidean)")
    ax.set_title("closed loop: each forecast against what the agents then did", fontsize=9)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(title="ego's forecasts", fontsize=8, title_fontsize=8)
    return _save(fig, path)


# ---------------------------------------------------------------------- open-loop prediction figures
def plot_rmse_curve(curves: dict[str, list[float]], path: Path | str, units: str = "m",
                    title: str = "RMSE per horizon second") -> Path:
    """The paper's Figure 5: RMSE at t = 1..S s per method. curves: name -> (S,) values."""
    path = Path(path)
    fig, ax = plt.subplots(figsize=(5.5, 4), dpi=120)
    for name, vals in curves.items():
        ref = name.lower().startswith(("const-vel", "constant velocity"))  # the reference, dashed
        ax.plot(np.arange(1, len(vals) + 1), vals, marker="s" if ref else "o", ls="--" if ref else "-", label=name)
    ax.set_xlabel("prediction horizon (s)")
    ax.set_ylabel(f"RMSE ({units})")
    ax.set_xticks(np.arange(1, max((len(v) for v in curves.values()), default=1) + 1))
    ax.set_ylim(bottom=0)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(title="predictor", fontsize=8, title_fontsize=8)
    return _save(fig, path)


def _sigma_ellipses(mean: np.ndarray, sigma_rho: np.ndarray) -> list[np.ndarray]:
    """1-sigma ellipses (K, 40, 2) of points mean (K, 2), sigma_rho (K, 3)."""
    sx, sy, rho = sigma_rho[:, 0], sigma_rho[:, 1], sigma_rho[:, 2]
    cov = np.stack([np.stack([sx**2, rho * sx * sy], -1), np.stack([rho * sx * sy, sy**2], -1)], -2)
    vals, vecs = np.linalg.eigh(cov)
    a = np.linspace(0, 2 * np.pi, 40)
    circle = np.stack([np.cos(a), np.sin(a)], -1)  # (40, 2)
    pts = np.einsum("kij,kj,aj->kai", vecs, np.sqrt(np.maximum(vals, 0)), circle)
    return list(pts + mean[:, None])


def plot_forecasts(scene: Scene, now: int, rows: np.ndarray, history: np.ndarray, truth: np.ndarray,
                   mean: np.ndarray, path: Path | str, sigma_rho: np.ndarray | None = None,
                   road: RoadGeometry | None = None, title: str | None = None, every: int = 5,
                   panels: int = 4) -> Path:
    """The paper's Figure 4: for targets `rows` (M,) their history (M, H, 2) in black, ground truth (M, F, 2)
    green, prediction (M, F, 2) red with 1-sigma ellipses every `every` frames, over the traffic at `now`.

    One zoomed panel per target (the first `panels` targets), so that metres stay readable on a long road.
    """
    path = Path(path)
    valid = scene.valid[:, now]
    k = max(1, min(panels, len(rows)))
    fig, axes = plt.subplots(k, 1, figsize=(9, 2.0 * k), dpi=120, squeeze=False)
    ell = None
    if sigma_rho is not None:
        idx = np.arange(every - 1, mean.shape[1], every)
        ell = np.asarray(_sigma_ellipses(mean[:, idx].reshape(-1, 2), sigma_rho[:, idx].reshape(-1, 3)))
        ell = ell.reshape(len(rows), len(idx), *ell.shape[1:])
    for m, ax in enumerate(axes[:, 0]):
        draw_road(ax, road)
        draw_agents(ax, scene.xy[valid, now], box_heading(scene)[valid, now], scene.length[valid], scene.width[valid],
                    scene.agent_type[valid], highlight=np.flatnonzero(valid) == rows[m])
        ax.add_collection(LineCollection(list(history), colors="black", linewidths=1.0, alpha=0.4, zorder=4))
        ax.plot(*history[m].T, color="black", lw=1.6, zorder=5, label="history")
        ax.plot(*truth[m].T, color="#2ca02c", lw=1.8, zorder=5, label="ground truth")
        ax.plot(*mean[m].T, color="#d62728", lw=1.8, zorder=6, label="prediction")
        if ell is not None:
            ax.add_collection(PolyCollection(list(ell[m]), facecolor="#d62728", alpha=0.15, edgecolor="#d62728",
                                             linewidths=0.3, zorder=4))
        pts = np.concatenate([history[m], truth[m], mean[m]])
        centre, half = (pts.min(0) + pts.max(0)) / 2, np.maximum((pts.max(0) - pts.min(0)) / 2 + 8, [30, 9])
        ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
        ax.set_ylim(centre[1] - half[1], centre[1] + half[1])
        ax.set_aspect("equal")
        ax.set_ylabel(f"y ({scene.units})")
        kind = AgentType(int(scene.agent_type[rows[m]])).label
        ax.set_title(f"{kind} {scene.agent_id[rows[m]]}", fontsize=9)
        if m == 0:  # the lines, then the agent types present
            lines = ax.get_legend_handles_labels()[0]
            target = Patch(facecolor="white", edgecolor="red", lw=1.2, label="the target")
            type_legend(ax, scene.agent_type[valid], extra=[*lines, target])
    axes[-1, 0].set_xlabel(f"x ({scene.units})")
    fig.suptitle(title or f"t = {scene.times[now]:.1f} s: history (black), truth (green), "
                          "prediction (red, 1-sigma ellipses)", fontsize=10)
    return _save(fig, path)


def plot_sweep(points: list[dict], axis: str, path: Path | str, title: str = "",
               panels: tuple[tuple[str, str], ...] = (("collision_rate", "collision rate (share of episodes)"),
                                                      ("online_ade", "online ADE (m, mean Euclidean)"))) -> Path:
    """Sweep figure: one panel per metric against the swept setting `axis`, mean with 95% CI bars.

    points: [{"settings": {axis: value, ...}, "group": line label, metric: {"mean", "lo", "hi", "n"}}, ...];
    one line per group; a numeric axis is drawn to scale, any other as categories in the given order.
    """
    path = Path(path)
    values = list(dict.fromkeys(p["settings"][axis] for p in points))
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    xpos = {v: (float(v) if numeric else float(i)) for i, v in enumerate(values)}
    groups = list(dict.fromkeys(p["group"] for p in points))
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4), dpi=120, squeeze=False)
    for ax, (key, label) in zip(axes[0], panels, strict=True):
        for j, g in enumerate(groups):
            mine = sorted((p for p in points if p["group"] == g), key=lambda p: xpos[p["settings"][axis]])
            x = np.array([xpos[p["settings"][axis]] for p in mine])
            ci = np.array([[p[key]["mean"], p[key]["lo"], p[key]["hi"]] for p in mine], float)  # (P, 3)
            shift = (j - (len(groups) - 1) / 2) * 0.02 * (np.ptp(x) if numeric and np.ptp(x) > 0 else 1.0)
            ax.errorbar(x + shift, ci[:, 0], yerr=np.abs(ci[:, 1:].T - ci[:, 0]), marker="o", capsize=4, label=g)
        ax.set_xlabel(axis)
        ax.set_ylabel(label)
        if key.endswith("_rate"):
            ax.set_ylim(-0.05, 1.05)  # a share of episodes: always on the whole scale
        if not numeric:
            ax.set_xticks(list(xpos.values()), [str(v) for v in values])
        ax.grid(alpha=0.3)
    if len(groups) > 1 or groups[0]:
        axes[0, 0].legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


# ---------------------------------------------------------------------- benchmark figures
def plot_method_bars(rows: dict[str, tuple[float, float, float]], path: Path | str, units: str = "m") -> Path:
    """Per method: ADE-RMSE and FDE-RMSE bars (left) and training wall time (right).

    rows: label -> (ADE-RMSE, FDE-RMSE in `units`, training seconds).
    """
    path = Path(path)
    names = list(rows)
    vals = np.array([rows[n] for n in names], dtype=np.float64).reshape(-1, 3)
    x = np.arange(len(names))
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4), dpi=120, gridspec_kw={"width_ratios": [2, 1]})
    ax.bar(x - 0.2, vals[:, 0], 0.4, label="ADE (RMSE)")
    ax.bar(x + 0.2, vals[:, 1], 0.4, label="FDE (RMSE)")
    ax.set_ylabel(f"error ({units})")
    ax2.bar(x, vals[:, 2], 0.6, color="#7f7f7f")
    ax2.set_ylabel("training wall time (s)")
    for a in (ax, ax2):
        a.set_xticks(x, names, rotation=35, ha="right", fontsize=8)
        a.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("prediction error per method")
    ax2.set_title("training time")
    return _save(fig, path)
