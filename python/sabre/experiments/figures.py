"""Figures (PNG, in the paper's form) and ``summary.md`` tables of the experiments' run records."""

from __future__ import annotations

import datetime
import os
import platform
from collections import defaultdict
from typing import Any

import numpy as np

from ..errors import require_extra

#: the paper's reported numbers, next to which the summary puts sabre's
PAPER = {
    "fig11": "hardware stuck door: mean wrench 68 N without the tank (N) and 34 N with it (IO)",
    "fig12": "α = 1 keeps the tank above its floor smoothly; α = 1000 chatters at the floor",
    "fig8": "the safety-filtered variants (I, O, IO) have (near) zero cumulative violation; N does not",
    "fig10": "the filtered controller keeps out of the suddenly appearing obstacle",
    "fig3": "the invariant mapping (55) keeps the effective sample size independent of the cost scale",
    "fig4": "the tank energy stays above the floor ε in the worst case",
    "acceptance": "every object opens from the paper's start",
    "hook": "no counterpart in the paper: the hook's skill on generated objects (insertion, slips, re-insertion)",
    "unknown": "no counterpart in the paper (every object has a model there): objects opened from a handle's pose, "
    "their joint estimated while pulling",
    "transfer": "the controller planned in simulation opens the objects on the real robot (Sec. VI); here a second "
    "simulator (MuJoCo) stands in for it, with the object's damping and friction scaled and a 20 ms planning delay",
}


def _group(records: list[dict], key: str) -> dict:
    groups = defaultdict(list)
    for r in records:
        groups[r["config"][key]].append(r)
    return dict(groups)


def _mean_std(runs: list[dict], series: str, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ys = [np.interp(grid, r["series"][series]["t"], r["series"][series]["y"]) for r in runs]
    return np.mean(ys, axis=0), np.std(ys, axis=0)


def draw(name: str, records: list[dict], path: str | os.PathLike[str]) -> None:
    """Writes the experiment's figure to ``path``."""
    (matplotlib,) = require_extra("experiments", "the experiments' figures", "matplotlib")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    if name == "fig3":
        _draw_weights(ax, records)
    elif name in _TIME_SERIES:
        _draw_time_series(ax, name, records)
    elif name == "fig8":
        _draw_violations(ax, records)
    elif name == "fig10":
        _draw_hand_paths(ax, records)
    elif name == "acceptance":
        _draw_openings(ax, records)
    elif name == "transfer":
        _draw_transfer(ax, records)
    elif name == "hook":
        _draw_hook(ax, records)
    elif name == "unknown":
        _draw_unknown(ax, records)
    # fig11: its contact axis is on the right; unknown: its bars are inset on the right
    ax.legend(fontsize=8, loc="upper left" if name in ("fig11", "unknown") else "best")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _draw_weights(ax: Any, records: list[dict]) -> None:
    """Fig. 3: the normalised weight of each rollout, per weight mapping and cost scale."""
    for i, (mapping, runs) in enumerate(_group(records, "mapping").items()):
        for scale, scaled in _group(runs, "scale").items():
            w = scaled[0]["series"]["weights"]
            ess = np.mean([r["metrics"]["effective_samples"] for r in scaled])
            ax.plot(
                w["t"],
                w["y"],
                color=f"C{i}",
                ls="-" if scale == 1.0 else "--",
                marker=".",
                label=f"{mapping}, costs ×{scale:g} (ESS {ess:.1f})",
            )
    ax.set(
        xlabel="rollout, by increasing cost",
        ylabel="normalised weight",
        yscale="symlog",
        title="Fig. 3: likelihood weight mappings",
    )
    ax.set_yscale("symlog", linthresh=1e-3)


#: the figures of one series over time, mean ± std per group: (config key grouped by, series, title)
_TIME_SERIES = {
    "fig4": ("variant", "tank", "Fig. 4: tank energy, worst case"),
    "fig11": ("variant", "wrench", "Fig. 11: wrench on the stuck door (mean ± std)"),
    "fig12": ("alpha", "tank", "Fig. 12: tank energy for α = 1 and α = 1000"),
}


def _draw_time_series(ax: Any, name: str, records: list[dict]) -> None:
    """Figs. 4, 11 and 12: the tank energy or the wrist force around the hold, mean ± std per group."""
    key, series, title = _TIME_SERIES[name]
    for value, runs in _group(records, key).items():
        end = min(r["series"][series]["t"][-1] for r in runs)
        start = max(r["series"][series]["t"][0] for r in runs)
        grid = np.linspace(start, end, 300)
        mean, std = _mean_std(runs, series, grid)
        label = f"α = {value:g}" if key == "alpha" else str(value)
        ax.plot(grid, mean, label=label)
        # a force magnitude is never negative: its band stops at zero
        ax.fill_between(grid, np.maximum(mean - std, 0.0) if series == "wrench" else mean - std, mean + std, alpha=0.25)
    if series == "wrench" and all("contact" in r["series"] for r in records):
        # the hook's contact with the handle: the share of 0.1 s windows, mean over seeds
        twin = ax.twinx()
        for i, (value, runs) in enumerate(_group(records, key).items()):
            grid = np.linspace(
                max(r["series"]["contact"]["t"][0] for r in runs), min(r["series"]["contact"]["t"][-1] for r in runs), 300
            )
            twin.plot(grid, _mean_std(runs, "contact", grid)[0], color=f"C{i}", ls="--", lw=0.9, label=f"{value} in contact")
        twin.set(ylabel="hook in contact (share, dashed)", ylim=(0.0, 1.05))
        twin.legend(fontsize=8, loc="center right")
    if series == "tank":
        ax.axhline(2.0, color="k", ls="--", lw=0.8, label="floor ε")
    ax.axvline(0.0, color="grey", ls=":", lw=0.8)
    ylabel = "wrist force |f| (N)" if series == "wrench" else "tank energy (J)"
    ax.set(xlabel="time from the hold (s)", ylabel=ylabel, title=title)


def _draw_violations(ax: Any, records: list[dict]) -> None:
    """Fig. 8: cumulative constraint violation per class, a bar per variant."""
    groups = _group(records, "variant")
    classes = sorted({k for r in records for k in r["metrics"] if k.startswith("violation_")})
    width = 0.8 / max(1, len(groups))
    for i, (variant, runs) in enumerate(groups.items()):
        vals = np.array([[r["metrics"][c] for c in classes] for r in runs])
        ax.bar(np.arange(len(classes)) + i * width, vals.mean(axis=0), width, yerr=vals.std(axis=0), label=variant)
    ax.set_xticks(
        np.arange(len(classes)) + 0.4 - width / 2, [c.removeprefix("violation_") for c in classes], rotation=20, fontsize=8
    )
    # the classes differ by orders of magnitude (the base box from a start outside it, joint
    # limits within the slack): linear near zero, logarithmic above, so every bar shows
    ax.set_yscale("symlog", linthresh=1e-4)
    ax.set(ylabel="cumulative violation Δ_tot (symlog)", title="Fig. 8: constraint violation per class")


def _draw_hand_paths(ax: Any, records: list[dict]) -> None:
    """Fig. 10: the hand's path in the plane, per variant, around the suddenly appearing obstacle."""
    from matplotlib.patches import Circle

    for i, (variant, runs) in enumerate(_group(records, "variant").items()):
        for j, r in enumerate(runs):
            s = r["series"]["hand_xy"]
            ax.plot(s["t"], s["y"], color=f"C{i}", label=f"{variant} hand" if j == 0 else None)
    obstacle = records[0]["series"]["obstacle"]
    ax.add_patch(Circle((obstacle["t"][0], obstacle["y"][0]), 0.08, color="grey", alpha=0.5, label="obstacle (r = 8 cm)"))
    appeared = [r["metrics"]["appeared_at"] for r in records if np.isfinite(r["metrics"]["appeared_at"])]
    note = f", appears at {np.mean(appeared):.1f} s" if appeared else ", never reached"
    ax.set(xlabel="x (m)", ylabel="y (m)", title=f"Fig. 10: hand path with the sudden obstacle{note}", aspect="equal")


def _draw_openings(ax: Any, records: list[dict]) -> None:
    """Acceptance: the opening over time of every run, coloured by object, with its success rate."""
    for i, (obj, runs) in enumerate(_group(records, "obj").items()):
        success = np.mean([q["metrics"]["success"] for q in runs])
        for r in runs:
            s = r["series"]["opening"]
            ax.plot(s["t"], s["y"], color=f"C{i}", lw=1, label=f"{obj} ({success:.0%} success)" if r is runs[0] else None)
    variants = ", ".join(sorted({r["config"]["variant"] for r in records}))
    ax.set(xlabel="time (s)", ylabel="opening (rad or m)", title=f"Acceptance: opening from the paper's start ({variants})")


def _draw_transfer(ax: Any, records: list[dict]) -> None:
    """Transfer: the share of episodes that opened per object and variant, one bar per plant and scale."""
    groups: defaultdict[tuple[str, float], defaultdict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        c = r["config"]
        groups[c["simulator"], c["scale"]][f"{c['obj']} {c['variant']}"].append(r["metrics"]["success"])
    labels = sorted({label for runs in groups.values() for label in runs})
    width = 0.8 / max(1, len(groups))
    for i, ((simulator, scale), runs) in enumerate(sorted(groups.items())):
        rates = [np.mean(runs[label]) if runs.get(label) else np.nan for label in labels]
        ax.bar(np.arange(len(labels)) + i * width, rates, width, label=f"{simulator} ×{scale:g}")
    ax.set_xticks(np.arange(len(labels)) + 0.4 - width / 2, labels, rotation=45, ha="right", fontsize=7)
    ax.set(ylabel="opened", ylim=(0, 1.05), title="Transfer: Rapier and MuJoCo plants, object damping and friction scaled")


def _draw_hook(ax: Any, records: list[dict]) -> None:
    """Hook: per family, handle class, robot and variant, the share of runs that opened and of first
    inserts that reached the hook."""
    groups: defaultdict[str, list[dict]] = defaultdict(list)
    for r in records:
        c = r["config"]
        groups[f"{c['family']}, {r['handle_class']}, {c['variant']}"].append(r)
    labels = sorted(groups)
    x = np.arange(len(labels))
    for i, (metric, label) in enumerate((("inserted", "first insert hooked"), ("success", "opened"))):
        rates = [np.mean([r["metrics"][metric] for r in groups[g]]) for g in labels]
        ax.bar(x + 0.4 * i, rates, 0.4, label=label)
    robots = ", ".join(sorted({r["config"].get("robot", "royalpanda") for r in records}))
    ax.set_xticks(x + 0.2, labels, rotation=30, ha="right", fontsize=7)
    ax.set(ylabel="share of runs", ylim=(0, 1.05), title=f"Hook: generated objects ({robots})")


def _draw_unknown(ax: Any, records: list[dict]) -> None:
    """Unknown: the hinge axis's error against the true opening in every estimated door run, and per
    object group and variant the share opened with the model and from the handle alone (inset bars)."""
    for r in records:
        s = r["series"].get("axis_error")
        if s and r["kind"] == "revolute" and s["t"]:
            ax.plot(np.degrees(s["t"]), s["y"], lw=0.6, alpha=0.6, color="C0")
    ax.plot([], [], color="C0", label="estimated hinge axis error (each door run)")
    ax.axvline(15.0, color="0.5", ls=":", lw=0.8)
    ax.axhline(3.0, color="0.5", ls=":", lw=0.8)
    ax.set(xlabel="true opening (°)", ylabel="axis error (°)", ylim=(0, 10), title="Unknown objects: estimate and success")
    inset = ax.inset_axes((0.6, 0.5, 0.38, 0.42))
    groups: defaultdict[str, defaultdict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        c = r["config"]
        groups[f"{c['case']} {c['variant']}"][c["mode"]].append(r["metrics"]["success"])
    labels = sorted(groups)
    x = np.arange(len(labels))
    for i, mode in enumerate(("known", "unknown", "wrong prior")):
        inset.bar(x + 0.27 * i, [np.mean(groups[g][mode]) if groups[g][mode] else 0.0 for g in labels], 0.27, label=mode)
    inset.set_xticks(x + 0.27, labels, rotation=30, ha="right", fontsize=6)
    inset.set_ylim(0, 1.05)
    inset.tick_params(labelsize=6)
    inset.legend(fontsize=5, loc="lower left", framealpha=0.6)
    inset.set_title("opened (share)", fontsize=7)


def cpu_name() -> str:
    """The processor's model name as ``lscpu`` gives it (from /proc/cpuinfo), else the machine type."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return f"{line.split(':', 1)[1].strip()}, {os.cpu_count()} CPUs"
    except OSError:
        pass
    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs"


def _options(name: str, records: list[dict]) -> str:
    """The command-line options besides seeds that the records were run with (robot, objects per family)."""
    robots = {r["config"].get("robot", "royalpanda") for r in records}
    text = f" --robot {robots.pop()}" if len(robots) == 1 and "royalpanda" not in robots else ""
    if name == "hook" and records:
        text += f" --objects {1 + max(r['config']['index'] for r in records)}"
    if name == "unknown":
        generated = [r["config"]["object"] for r in records if r["config"]["case"] != "builtin"]
        text += f" --objects {1 + max(generated) if generated else 0}"
    return text


def summary(name: str, records: list[dict], *, seeds: int, short: bool) -> str:
    """Markdown: the command, the machine and date, mean ± std of every metric per configuration,
    and the paper's reported result."""
    rows: defaultdict[str, defaultdict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        label = ", ".join(f"{k}={v}" for k, v in sorted(r["config"].items()))
        for k, v in r["metrics"].items():
            rows[label][k].append(v)
    metrics = sorted({k for r in records for k in r["metrics"]})
    lines = [
        f"# {name}",
        "",
        f"`python -m sabre experiment {name} --seeds {seeds}{' --short' if short else ''}{_options(name, records)}` on "
        f"{datetime.date.today().isoformat()}, {platform.node()} ({cpu_name()}, {platform.python_version()})",
        "",
        f"Paper: {PAPER[name]}.",
        "",
    ]
    if name == "hook":  # one run per object: the table per family, handle class, robot and variant says it
        from .hook import hook_table

        return "\n".join([*lines, hook_table(records)]) + "\n"
    if name == "unknown":
        from .unknown import unknown_table

        return "\n".join([*lines, unknown_table(records)]) + "\n"
    lines += [
        "| configuration | " + " | ".join(metrics) + " |",
        "|---" * (len(metrics) + 1) + "|",
    ]
    for label, values in rows.items():
        cells = []
        for m in metrics:
            v = np.asarray(values.get(m, []), dtype=float)
            v = v[np.isfinite(v)]
            cells.append("—" if v.size == 0 else f"{v.mean():.3g} ± {v.std():.2g}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    if name == "acceptance":
        lines += ["", acceptance_table(records)]
    if name == "transfer":
        from .transfer import transfer_table

        lines += ["", transfer_table(records)]
    return "\n".join(lines) + "\n"


def acceptance_table(records: list[dict]) -> str:
    """Markdown, one row per object and variant: episodes that opened, time to open, final opening
    against the one success needs, mean wrench, real-time factor, planning time (medians over seeds)
    and the seeds that did not open. The object is prefixed with its robot when that is not the RoyalPanda."""
    groups: defaultdict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in records:
        robot = r["config"].get("robot")
        groups[r["config"]["obj"] if robot is None else f"{robot}: {r['config']['obj']}", r["config"]["variant"]].append(r)
    lines = [
        "| object | variant | opened | time to open (median, max) | final opening, median (needed) "
        "| mean wrench, median | real-time factor, median | planning, median | seeds not opened |",
        "|---" * 9 + "|",
    ]
    for (obj, variant), runs in groups.items():
        median = {
            m: float(np.median([r["metrics"][m] for r in runs]))
            for m in ("final_opening", "needed_opening", "mean_wrench", "real_time_factor", "planning_ms_median")
        }
        opened = [r for r in runs if r["metrics"]["success"]]
        times = [r["metrics"]["time_to_success"] for r in opened]
        when = f"{np.median(times):.1f} s, {max(times):.1f} s" if times else "—"
        failed = ", ".join(str(r["seed"]) for r in runs if not r["metrics"]["success"]) or "—"
        lines.append(
            f"| {obj} | {variant} | {len(opened)}/{len(runs)} | {when} "
            f"| {median['final_opening']:.3f} ({median['needed_opening']:.3f}) | {median['mean_wrench']:.1f} N "
            f"| {median['real_time_factor']:.2f} | {median['planning_ms_median']:.1f} ms | {failed} |"
        )
    return "\n".join(lines)
