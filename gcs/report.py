"""The flight report: a Markdown page of what was planned, what was flown and how well.

Written by ``gcs demo`` (``<out>/report.md``, next to the picture) and by ``gcs fly --log DIR``
(``DIR/report.md``). Sections: a summary table (planned and flown robustness, planning and
flight time, completion), the wall-time split, how the plan was made to a probability
(``gcs plan --target-probability``: its record and the margin of each tightened clause), the
picture (``gcs.plot``'s figure with the
flown tracks over the plan) when there is one, every top-level clause with its planned and
flown robustness (weakest flown first), tracking errors per vehicle, the setpoint stream's
timing, and the files written. Markdown reads as plain text in a terminal and renders with
the picture in any Markdown viewer.

Errors::

    gcs.errors.InputFileError   the report cannot be written
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from gcs.errors import InputFileError

if TYPE_CHECKING:
    from gcs.flight.outcome import FlightOutcome
    from planner.planfile import Plan

__all__ = ["report_markdown", "write_report"]


def _num(x: float | None, fmt: str = "+.4f") -> str:
    if x is None or not math.isfinite(x):
        return "n/a"
    return format(x, fmt)


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def report_markdown(
    plan: Plan,
    outcome: FlightOutcome,
    *,
    title: str,
    base_dir: Path,
    timings_s: Mapping[str, float] | None = None,
    picture: Path | None = None,
    files: Mapping[str, Path] | None = None,
) -> str:
    """The report as Markdown text.

    Args:
        plan: the plan flown.
        outcome: what :func:`gcs.flight.fly_plan` returned.
        title: the heading (scenario or plan name).
        base_dir: links to files are written relative to this directory.
        timings_s: wall-time split by stage, seconds (e.g. set-up, planning, flight).
        picture: the figure to embed (PNG).
        files: further files to list, by description.
    """

    def rel(p: Path) -> str:
        try:
            return Path(os.path.relpath(p, base_dir)).as_posix()
        except ValueError:  # another drive (Windows)
            return p.as_posix()

    ev = outcome.evaluation
    lines = [f"# stl-gcs flight report: {title}", ""]
    lines += [
        f"Scenario `{plan.scenario}`, {len(plan.vehicles)} vehicle(s) "
        f"({', '.join(v.name for v in plan.vehicles)}), horizon {plan.horizon_s:g} s, "
        f"flown in {outcome.mode.value} mode. Robustness is the exact STL semantics of the spec "
        f"(metres of margin; > 0 means satisfied) on the plan's check grid"
        + (f" (every {ev.dt_s:g} s)." if ev is not None else "."),
        "",
        "| | |",
        "|---|---|",
        f"| planned robustness | {_num(ev.planned_robustness if ev else None)} |",
        f"| flown robustness (on the vehicles' estimates) | "
        f"{_num(ev.flown_robustness if ev else None)} |",
        f"| flown robustness, at least, within the estimators' reported accuracy | "
        f"{_num(outcome.flown_lower_bound)} |",
        f"| planner status | {_cell(plan.status)} |",
        f"| planning time | {plan.solve_time_s:.2f} s |",
        f"| connection | {outcome.connect_s:.2f} s |",
        f"| flight (take-off to end action) | {outcome.flight_s:.2f} s |",
        f"| completed | {'yes' if outcome.completed else 'no'} |",
        f"| modes at the end | {', '.join(f'{k} {m}' for k, m in outcome.final_modes.items())} |",
    ]
    if ev is not None and ev.coverage_problem:
        lines.append(f"| flown robustness not evaluated | {_cell(ev.coverage_problem)} |")
    if outcome.safety_event is not None:
        lines.append(f"| safety stop | {_cell(outcome.safety_event.describe())} |")
    if outcome.monitor is not None and outcome.monitor.stale:
        lines.append(f"| late telemetry | {_cell(outcome.monitor.describe_stale())} |")
    if outcome.monitor is not None and outcome.monitor.unheard:
        lines.append(f"| link lost | {_cell(outcome.monitor.describe_unheard())} |")
    for line in ev.describe_gaps() if ev is not None else ():
        lines.append(f"| telemetry missed | {_cell(line)} |")
    if outcome.interrupted:
        lines.append("| interrupted | Ctrl-C: every vehicle was commanded to hold |")
    for name, why in outcome.end_failures.items():
        lines.append(f"| end action failed ({name}) | {_cell(why)} |")
    for vehicle, heard in outcome.vehicle_messages.items():
        for t_said, severity, text in heard:
            when = "the plan never started" if t_said is None else f"t = {t_said:.2f} s"
            lines.append(f"| {vehicle} said ({severity}) | {_cell(text)}, {when} |")
    lines.append("")
    if timings_s:
        total = sum(timings_s.values())
        lines += ["## Wall time", "", "| stage | s | share |", "|---|---:|---:|"]
        for stage, s in timings_s.items():
            share = 100.0 * s / total if total > 0 else 0.0
            lines.append(f"| {stage} | {s:.2f} | {share:.0f} % |")
        lines += [f"| total | {total:.2f} | |", ""]
    if outcome.replans:
        lines += [
            "## Replans",
            "",
            "Each vehicle that left the flight, the plan made for the others from the switch "
            "time on (`gcs fly --replan`), and what became of the clauses that read it."
            + (
                " The flight is judged on the spec as amended by the last replan, on the "
                "vehicles that flew on."
                if outcome.judged_spec is not None
                else ""
            ),
            "",
            "| event | switch at s | solved in s | new plan ρ | flown |",
            "|---|---:|---:|---:|---|",
        ]
        for rp in outcome.replans:
            flown = "yes" if rp.success else f"no: {rp.reason}"
            lines.append(
                f"| {_cell(rp.event)} | {rp.switch_s:g} | {rp.solve_s:.2f} | "
                f"{_num(rp.robustness)} | {_cell(flown)} |"
            )
        lines.append("")
        for rp in outcome.replans:
            for what, texts in rp.fates():
                lines += [f"- {what}: `{_cell(t)}`" for t in texts]
        lines.append("")
    a = plan.assurance
    if a is not None:
        lines += ["## Planned to a probability", "", _cell(a.summary()), ""]
        if a.margins:
            lines += ["| margin m | clause (tightened by it when planned) |", "|---:|---|"]
            for text, margin in sorted(a.margins.items(), key=lambda kv: -kv[1]):
                lines.append(f"| {margin:.2f} | `{_cell(text)}` |")
            lines.append("")
    if picture is not None:
        lines += [
            "## Picture",
            "",
            "Regions and paths (flown dashed over planned), clause robustness over time, "
            "per-axis velocity and acceleration against the limits.",
            "",
            f"![plan and flown tracks]({rel(picture)})",
            "",
        ]
    if ev is not None:
        lines += [
            "## Clauses",
            "",
            "| flown ρ | planned ρ | clause |",
            "|---:|---:|---|",
        ]
        order = sorted(
            ev.clauses, key=lambda c: (c.flown if c.flown is not None else math.inf, c.planned)
        )
        for c in order:
            lines.append(f"| {_num(c.flown)} | {_num(c.planned)} | `{_cell(c.text)}` |")
        lines += [
            "",
            "## Tracking",
            "",
            "Distance between each vehicle's reported position and its plan at the same "
            "instant, and the delay that best aligns the two (flown(t) against planned(t - delay)).",
            "",
            "| vehicle | samples | max m | at t s | rms m | best-fit delay s | rms at delay m |",
            "|---|---:|---:|---:|---:|---:|---:|",
        ]
        margin = plan.robustness
        for t in ev.tracking:
            over = " (over the plan's margin)" if margin > 0 and t.max_m > margin else ""
            lines.append(
                f"| {t.vehicle} | {t.samples} | {_num(t.max_m, '.3f')}{over} | "
                f"{_num(t.t_at_max_s, '.2f')} | {_num(t.rms_m, '.3f')} | {_num(t.lag_s, '+.2f')} | "
                f"{_num(t.rms_at_lag_m, '.3f')} |"
            )
        lines.append("")
    if outcome.stats:
        lines += [
            "## Setpoint stream",
            "",
            "Lateness of each setpoint send after its absolute deadline.",
            "",
            "| vehicle | rate Hz | sent | skipped | failed | late | mean ms | p99 ms | max ms |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for st in outcome.stats.values():
            lines.append(
                f"| {st.vehicle} | {st.rate_hz:g} | {st.sent} | {st.skipped} | {st.failed} "
                f"| {st.late} | {_num(st.mean_lateness_s * 1e3, '.3f')} "
                f"| {_num(st.p99_lateness_s * 1e3, '.3f')} | {_num(st.max_lateness_s * 1e3, '.3f')} |"
            )
        lines.append("")
    if outcome.missions:
        lines += [
            "## Missions",
            "",
            "| vehicle | finished | s | items reached |",
            "|---|---|---:|---:|",
        ]
        for name, r in outcome.missions.items():
            lines.append(
                f"| {name} | {'yes' if r.finished else 'no'} | {r.duration_s:.1f} | {len(r.reached)} |"
            )
        lines.append("")
        m = outcome.mission
        if m is not None:
            conv = m.conversion
            lines += [
                f"Acceptance radius {conv.acceptance_m:.2f} m; robustness predicted "
                f"{conv.predicted_robustness:+.4f} (straight legs on time "
                f"{conv.straight_leg_robustness:+.4f}).",
                "",
                "| vehicle | s after the plan | predicted | start skew ms |",
                "|---|---:|---:|---:|",
            ]
            for name in outcome.missions:
                lines.append(
                    f"| {name} | {_num(m.late_s.get(name), '+.1f')} | "
                    f"{_num(conv.late_s.get(name), '+.1f')} | "
                    f"{_num(m.start_skew_s.get(name, 0.0) * 1e3, '+.0f')} |"
                )
            lines.append("")
    if outcome.tuning:
        lines += [
            "## Drag and estimator",
            "",
            "| vehicle | drag 1/s | from | estimator accuracy m (h / v) |",
            "|---|---:|---|---|",
        ]
        for name, tu in outcome.tuning.items():
            acc = outcome.accuracy_m.get(name)
            accs = f"{acc[0]:.2f} / {acc[1]:.2f}" if acc is not None else "n/a"
            lines.append(f"| {name} | {tu.drag_per_s:.2f} | {tu.drag_source} | {accs} |")
        lines.append("")
    listed = dict(files or {})
    for kind, p in outcome.files.items():
        listed.setdefault(
            {"tlog": "telemetry (.tlog)", "csv": "flown tracks (CSV)"}.get(kind, kind), p
        )
    if outcome.tlog is not None:
        lines.append(
            f"The telemetry log holds {outcome.tlog.messages} messages "
            f"({len(outcome.tlog.by_type)} types) from the vehicles."
        )
        lines.append("")
    if listed:
        lines += ["## Files", ""]
        lines += [f"- {what}: [{rel(p)}]({rel(p)})" for what, p in listed.items()]
        lines.append("")
    return "\n".join(lines)


def write_report(path: str | Path, plan: Plan, outcome: FlightOutcome, **kwargs: object) -> Path:
    """Write :func:`report_markdown` to ``path`` (links relative to its directory)."""
    p = Path(path)
    text = report_markdown(plan, outcome, base_dir=p.parent, **kwargs)  # type: ignore[arg-type]
    try:
        p.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise InputFileError(f"{p}: cannot write the report: {exc.strerror or exc}") from None
    return p
