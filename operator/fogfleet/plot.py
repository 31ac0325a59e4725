"""``fogfleet plan --plot FILE.png``: the Pareto front and the chosen plan's node utilisation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fogfleet.domain.problem import Problem
from fogfleet.scheduling.schedule import Schedule

__all__ = ["plot_plan"]


def plot_plan(problem: Problem, schedule: Schedule, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_front, ax_util) = plt.subplots(1, 2, figsize=(12, 4.5))
    front = schedule.pareto_front
    names = schedule.objective_names
    if front is not None and len(names) >= 2 and len(front):
        # the first two objectives (in priority order) that actually vary along the front
        varying = [k for k in range(len(names)) if np.ptp(front[:, k]) > 0] or [0]
        a, b = (varying + [k for k in range(len(names)) if k not in varying])[:2]
        x, y = names[a], names[b]
        ax_front.scatter(front[:, a], front[:, b], s=18, label="non-dominated plans")
        ax_front.scatter(
            [schedule.objectives[x]],
            [schedule.objectives[y]],
            s=80,
            marker="*",
            color="crimson",
            label="chosen",
        )
        ax_front.set_xlabel(x)
        ax_front.set_ylabel(y)
        ax_front.legend()
        ax_front.set_title(f"Pareto front ({len(front)} plans)")
    else:
        ax_front.text(0.5, 0.5, f"{schedule.scheduler}: no Pareto front", ha="center", va="center")
        ax_front.set_axis_off()
    alloc = problem.allocation(schedule.with_limits)
    used = np.zeros(problem.n_nodes)
    for i, j in enumerate(schedule.placement):
        if j >= 0:
            used[j] += alloc.cpu_request[i, j]
    labels = [n.name for n in problem.nodes]
    colors = [
        "tab:orange"
        if n.tier.value == "robot"
        else "tab:blue"
        if n.tier.value == "edge"
        else "tab:green"
        for n in problem.nodes
    ]
    ax_util.bar(labels, 100 * used / problem.capacity[:, 0], color=colors)
    ax_util.axhline(100, color="grey", lw=0.8, ls="--")
    ax_util.set_ylabel("requested CPU, % of allocatable")
    ax_util.set_title(f"Node utilisation ({schedule.scheduler})")
    ax_util.tick_params(axis="x", rotation=60)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
