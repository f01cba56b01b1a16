"""Figures of closed-loop episodes: :func:`plot_episode` (matplotlib, the ``plot`` extra)."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from ..episode import Episode
from ..errors import InvalidValueError, require_extra

if TYPE_CHECKING:
    from matplotlib.axes import Axes

__all__ = ["plot_episode"]

#: Fill colours of the phase spans, by phase index (cycled).
_PHASE_COLOURS = ("#dbe9f6", "#fde2c8", "#e3f1dc", "#f3dcef", "#f6f2c8", "#e0e0e0")


def _pyplot():
    (matplotlib,) = require_extra("plot", "sabre.plot_episode", "matplotlib")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _patch():
    from matplotlib.patches import Patch

    return Patch


def _phase_spans(episode: Episode) -> list[tuple[float, float, int]]:
    """(start, end, phase index) of each run of equal phase, in s."""
    t, phase = episode.time, episode.phase
    if len(t) == 0:
        return []
    cuts = np.flatnonzero(np.diff(phase)) + 1
    starts = np.r_[0, cuts]
    ends = np.r_[cuts, len(t)]
    return [(float(t[s - 1]) if s > 0 else 0.0, float(t[e - 1]), int(phase[s])) for s, e in zip(starts, ends)]


def _shade(ax: Axes, spans: list[tuple[float, float, int]]) -> None:
    for k, (start, end, index) in enumerate(spans):
        ax.axvspan(start, end, color=_PHASE_COLOURS[index % len(_PHASE_COLOURS)], lw=0, zorder=0)
        if k > 0:
            ax.axvline(start, color="0.55", lw=0.6, zorder=0.5)


def plot_episode(episode: Episode, path: str | os.PathLike) -> None:
    """Writes a PNG of an episode (:func:`sabre.run_episode`) to ``path``: four panels.

    - opening (rad or m) over time, with the target opening and the success threshold when the
      episode knows them (``Episode.target_opening``, ``Episode.success_opening``);
    - wrist force |f| (N) over time; the axis ends at 1.2 × the 99th percentile of the steps in
      contact, so that a few impact peaks do not flatten the rest (the peak is in the title);
    - the energy tank S (J) with its floor ε;
    - the base's path in the plane (m), start and end marked.

    The time panels shade each task phase and name it where it begins.

    Raises:
        MissingExtraError: matplotlib is missing (install the ``plot`` extra).
        InvalidValueError: the episode has no recorded steps.
    """
    if len(episode.time) == 0:
        raise InvalidValueError("episode: no recorded steps to plot")
    plt = _pyplot()
    Patch = _patch()
    unit = "rad" if episode.scene.object_is_revolute else "m"
    spans = _phase_spans(episode)
    t_end = float(episode.time[-1])
    fig, axes = plt.subplots(2, 2, figsize=(13, 7.5))
    ax_open, ax_force, ax_tank, ax_base = axes[0, 0], axes[0, 1], axes[1, 0], axes[1, 1]
    for ax in (ax_open, ax_force, ax_tank):
        _shade(ax, spans)
        ax.set_xlim(0.0, t_end)
        ax.set_xlabel("time (s)")
        ax.grid(alpha=0.3)

    opening = episode.opening
    ax_open.plot(episode.time, opening, color="C0", label="opening")
    top = float(np.nanmax(opening))
    if episode.target_opening is not None:
        ax_open.axhline(episode.target_opening, color="k", ls="--", lw=1, label=f"target {episode.target_opening:.2f} {unit}")
        top = max(top, episode.target_opening)
    if episode.success_opening is not None:
        label = f"success {episode.success_opening:.2f} {unit}"
        ax_open.axhline(episode.success_opening, color="C2", ls=":", lw=1.2, label=label)
    lower = float(min(0.0, np.nanmin(opening)))
    span = top - lower if top > lower else 1.0
    ax_open.set_ylim(lower - 0.03 * span, lower + 1.12 * span)
    verdict = f"opened at {episode.time_to_success:.1f} s" if episode.time_to_success is not None else "not opened"
    ax_open.set(ylabel=f"opening ({unit})", title=f"{episode.scene.object_name}, variant {episode.variant}: {verdict}")
    ax_open.legend(loc="lower right", fontsize=8)
    seen = sorted({index for _, _, index in spans})
    phase_patches = [Patch(color=_PHASE_COLOURS[i % len(_PHASE_COLOURS)], label=episode.phases[i]) for i in seen]

    force = np.linalg.norm(episode.wrench[:, :3], axis=1)
    peak = float(force.max())
    ax_force.plot(episode.time, force, color="C3", lw=0.8)
    touching = force[force > 0.0]
    limit = 1.2 * float(np.percentile(touching, 99.0)) if len(touching) else 1.0
    ax_force.set_ylim(0.0, max(limit, 1.0))
    ax_force.set(ylabel="|f| (N)", title=f"wrist force (peak {peak:.0f} N)")
    ax_force.legend(handles=phase_patches, title="phase", loc="upper left", fontsize=8, title_fontsize=8)

    if episode.tank_energy is not None:
        ax_tank.plot(episode.time, episode.tank_energy, color="C4", label="tank energy S")
        ax_tank.axhline(episode.tank_floor, color="k", ls="--", lw=1, label=f"floor ε = {episode.tank_floor:.1f} J")
        high = float(max(np.nanmax(episode.tank_energy), episode.tank_floor))
        low = float(min(0.0, np.nanmin(episode.tank_energy)))
        ax_tank.set_ylim(low - 0.05 * (high - low), high + 0.1 * (high - low))
        ax_tank.legend(loc="upper right", fontsize=8)
    ax_tank.set(ylabel="S (J)", title="energy tank")

    _plot_base_path(ax_base, episode)

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_base_path(ax: Axes, episode: Episode) -> None:
    """The base's path in the plane (m), start, end and the object marked, on equal axes around all three."""
    scene = episode.scene
    base = scene.fk_many(scene.split_state(episode.state).q, scene.base_link)[:, :3, 3]
    x, y = base[:, 0], base[:, 1]
    ax.plot(x, y, color="C1")
    ax.plot(x[0], y[0], "o", color="C1", label="start")
    ax.plot(x[-1], y[-1], "s", color="C1", label="end")
    pose = episode.scene.object_pose
    ax.plot(pose[0, 3], pose[1, 3], "k^", label="object")
    xs = np.r_[x, pose[0, 3]]
    ys = np.r_[y, pose[1, 3]]
    centre = np.array([(xs.min() + xs.max()) / 2.0, (ys.min() + ys.max()) / 2.0])
    half = 0.55 * max(xs.max() - xs.min(), ys.max() - ys.min(), 0.5)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal")
    ax.set(xlabel="x (m)", ylabel="y (m)", title="base path")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
