"""The picture of an assessment: the robustness histogram, each clause's failures, and the
worst run's paths over the plan.

A room of its own because it is the one part of ``gcs assess`` that draws (matplotlib, Agg);
the numbers come from :class:`gcs.assess.stats.AssessResult` and, for the worst run, its
tracks flown again (:func:`gcs.assess.replay`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from planner.spec.cover import drawn_regions

if TYPE_CHECKING:
    from gcs.assess.stats import AssessResult
    from mavlink.mock.sim.batch import BatchFlights
    from planner.planfile import Plan

__all__ = ["plot_assessment"]


def plot_assessment(
    plan: Plan, result: AssessResult, worst: BatchFlights | None, path: Path
) -> Path:
    """Draw the campaign into ``path`` (PNG) and return it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8), constrained_layout=True)
    ax = axes[0]
    table = result.runs_table
    if table.size:
        lo = min(float(table["robustness"].min()), float(table["reported"].min()), 0.0)
        hi = max(float(table["robustness"].max()), float(table["reported"].max()), result.planned)
        bins = np.linspace(lo, hi, 41)
        ax.hist(table["robustness"], bins=bins, alpha=0.7, label="true positions")
        ax.hist(table["reported"], bins=bins, alpha=0.5, label="reported positions")
    ax.axvline(0.0, color="k", lw=1)
    ax.axvline(result.planned, color="g", ls="--", label=f"planned {result.planned:+.2f} m")
    ax.set_xlabel("exact robustness of the spec (m)")
    ax.set_ylabel("runs")
    ax.set_title(
        f"P(holds) {result.p:.3f} [{result.ci[0]:.3f}, {result.ci[1]:.3f}], {result.runs} runs"
    )
    ax.legend(fontsize=8)

    ax = axes[1]
    ranked = sorted(result.clauses, key=lambda c: -c.failures)[:12]
    labels = [c.text if len(c.text) <= 48 else c.text[:45] + "..." for c in ranked]
    y = np.arange(len(ranked))
    ax.barh(y, [c.failures for c in ranked], label="failed")
    ax.barh(y, [c.first_to_fail for c in ranked], alpha=0.7, label="broke first")
    ax.set_yticks(y, labels, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("runs")
    ax.set_title("clauses: failures (true positions)")
    ax.legend(fontsize=8)

    ax = axes[2]
    t = np.arange(round(plan.horizon_s / plan.check_dt_s) + 1) * plan.check_dt_s
    for k, v in enumerate(plan.vehicles):
        p = v.trajectory.position(t)
        line = ax.plot(p[:, 0], p[:, 1], lw=1, label=f"{v.name} plan" if k == 0 else None)
        if worst is not None:
            f = worst.true_enu_m[0, k]
            ax.plot(f[:, 0], f[:, 1], color=line[0].get_color(), lw=1.5, ls=":",
                    label="worst run (true)" if k == 0 else None)  # fmt: skip
    # seen from above: a box's rectangle, a prism's polygon (one not convex: its outline), a circle
    for r in drawn_regions(plan.regions):
        ax.add_patch(
            matplotlib.patches.Polygon(
                r.footprint_xy(), closed=True, fill=False, lw=0.6, color="0.5"
            )
        )
    title = "worst run over the plan"
    if result.worst:
        title += f" (seed {result.worst[0].seed}, {result.worst[0].true:+.2f} m)"
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
