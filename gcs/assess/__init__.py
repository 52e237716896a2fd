"""How likely is a plan to hold? A statistical assessment campaign (``gcs assess``).

A campaign flies the plan ``runs`` times in the batch simulator
(:mod:`mavlink.mock.sim.batch`: the mock PX4 vehicle's own physics, controller and estimator,
stepped for many runs at once), each run under disturbances drawn from the user's
distributions (:mod:`mavlink.mock.sim.disturbances`), and judges every run with the exact STL
semantics: the spec and each top-level clause, on where the vehicles really were (*true*) and
on what they reported (*reported*, what ``gcs fly`` evaluates).  The spec *holds* in a run when
its exact robustness on the true positions is > 0.

The runs are split into batches; a batch is one task: in this process (``workers=0``), or on
Ray, started locally for the campaign (``ray_address=None``) or an existing cluster.  A run is
determined by its seed (:func:`mavlink.mock.sim.batch.run_seed` of the campaign seed and its
index), so the statistics are the same whatever the split and wherever the batches run.
Batches come back as they finish (``on_batch``); an interrupt keeps the finished ones.

With ``monitor``, each batch is flown a second time on the same seeds under the flight-time
safety monitor of ``gcs fly`` (:meth:`mavlink.monitor.SafetyMonitor.evaluate_runs` inside the
simulator), which may stop a run; the statistics then say how often it stopped the flight,
why, and whether the stops were needed (:class:`gcs.assess.stats.MonitorSummary`).

Layering (docs/architecture.md, "The parts and their direction"): the simulator is the mock's; the orchestration, the
statistics and the report are here; the statistics are in :mod:`gcs.assess.stats`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import os
import socket
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from gcs.assess.stats import AssessResult, summarise
from gcs.errors import UserError
from gcs.flight.evaluation import heading_readers, plan_formula, reads_heading
from mavlink.mock.sim.batch import prepare, run_seed, simulate
from mavlink.mock.sim.disturbances import parse_disturbances
from mavlink.mock.sim.errors import MockConfigError
from mavlink.monitor import SafetyMonitor
from mavlink.monitor_findings import always_clause_indices, always_clauses

if TYPE_CHECKING:
    from gcs.assess.replanned import ReplannedRuns, ReplanSettings
    from mavlink.mock.sim.batch import BatchFlights, SimSetup
    from mavlink.mock.sim.disturbances import Distribution
    from mavlink.monitor import SafetyMonitor
    from planner.planfile import Plan

__all__ = [
    "AssessOptions",
    "BatchOutcome",
    "CampaignProgress",
    "assess",
    "evaluate_batch",
    "fly_batch",
    "replay",
]


@dataclass(frozen=True, slots=True)
class AssessOptions:
    """Settings of a campaign.

    Attributes:
        runs: how many runs (> 0).
        seed: the campaign seed (run ``i``'s seed is ``run_seed(seed, i)``).
        disturbances: per disturbance name, its distribution as text (others: defaults).
        profile: the simulated vehicle (``px4`` or ``ideal``, :mod:`mavlink.mock.sim.profiles`).
        params: PX4 parameters over the profile.
        rate_hz: setpoint rate, as ``gcs fly --rate``.
        drag_per_s: drag fed forward (1/s); ``None``: the vehicle's own, as ``gcs fly``.
        batch_size: runs per task.
        workers: 0 runs every batch in this process; otherwise on Ray with this many CPUs
            (``None``: all of this machine's, or the cluster's).
        ray_address: an existing Ray cluster (``None``: start one here for the campaign,
            or use ``RAY_ADDRESS`` when set).
        worst: how many of the worst runs to keep with their seeds.
        monitor: also fly every run under ``gcs fly``'s safety monitor, which may stop it
            (the run is flown twice on the same draws: without the monitor, then with it).
        max_off_plan_m: the monitor's off-plan bound, as ``gcs fly --max-off-plan``
            (``None``: none).
        replan: with ``monitor``, replan the runs stopped on a lost link as ``gcs fly
            --replan`` would and fly them again (:mod:`gcs.assess.replanned`; ``None``: no).
    """

    runs: int
    seed: int = 0
    disturbances: Mapping[str, str] = field(default_factory=dict)
    profile: str = "px4"
    params: Mapping[str, float] = field(default_factory=dict)
    rate_hz: float = 20.0
    drag_per_s: float | None = None
    batch_size: int = 250
    workers: int | None = None
    ray_address: str | None = None
    worst: int = 5
    monitor: bool = False
    max_off_plan_m: float | None = 3.0
    replan: ReplanSettings | None = None

    def __post_init__(self) -> None:
        bound = self.max_off_plan_m
        if bound is not None and not (math.isfinite(bound) and bound > 0):
            raise UserError(f"--max-off-plan: must be a number > 0 m, got {bound!r}")
        if not (isinstance(self.runs, int) and self.runs > 0):
            raise UserError(f"--runs: must be a whole number > 0, got {self.runs!r}")
        if not (isinstance(self.batch_size, int) and self.batch_size > 0):
            raise UserError(f"--batch-size: must be a whole number > 0, got {self.batch_size!r}")
        if self.workers is not None and not (isinstance(self.workers, int) and self.workers >= 0):
            raise UserError(f"--workers: must be a whole number >= 0, got {self.workers!r}")
        if not (isinstance(self.seed, int) and self.seed >= 0):
            raise UserError(f"--seed: must be a whole number >= 0, got {self.seed!r}")
        if self.replan is not None and not self.monitor:
            raise UserError("--replan: with --monitor only (the monitor hands a lost vehicle over)")


@dataclass(frozen=True, slots=True, eq=False)
class BatchOutcome:
    """What one batch sends back: per run its seed, robustness and draws (no tracks).

    Attributes:
        index: the first run's index in the campaign.
        seeds: ``(R,)`` the runs' seeds.
        true: ``(R,)`` the spec's exact robustness on the true positions.
        reported: ``(R,)`` on the reported positions (what ``gcs fly`` evaluates).
        clause_true, clause_reported: ``(R, C)`` per top-level clause.
        failsafe_s: ``(R,)`` the first offboard-loss failsafe of the run (NaN: none).
        lost_s: ``(R,)`` when the run's first vehicle was lost (disturbance ``lost``; NaN:
            none).
        draws: per disturbance ``(R,)`` (per run) or ``(R, V)`` (per vehicle).
        sim_s: seconds the batch took to fly and judge.
        monitored: with the safety monitor, the same runs flown under it.
        replanned: with ``--replan``, those runs with the lost vehicles replanned around.
    """

    index: int
    seeds: np.ndarray
    true: np.ndarray
    reported: np.ndarray
    clause_true: np.ndarray
    clause_reported: np.ndarray
    failsafe_s: np.ndarray
    lost_s: np.ndarray
    draws: dict[str, np.ndarray]
    sim_s: float
    monitored: MonitoredRuns | None = None
    replanned: ReplannedRuns | None = None


@dataclass(frozen=True, slots=True, eq=False)
class MonitoredRuns:
    """A batch's runs flown again under the safety monitor (same seeds, same draws).

    Attributes:
        true, reported: ``(R,)`` the spec's exact robustness (true, reported positions).
        clause_true: ``(R, C)`` per top-level clause, on the true positions.
        stop_s: ``(R,)`` when the monitor stopped the run (s from the plan's start; NaN:
            it did not).
        stop_code: ``(R,)`` why (:class:`mavlink.monitor.RunFindings` codes; 0: no stop).
        stop_clause: ``(R,)`` the top-level clause it stopped for (-1: none, or not a clause).
        stop_value: ``(R,)`` the clause's robustness (now or predicted), or for the off-plan
            alarm the distance from the plan (m).
    """

    true: np.ndarray
    reported: np.ndarray
    clause_true: np.ndarray
    stop_s: np.ndarray
    stop_code: np.ndarray
    stop_clause: np.ndarray
    stop_value: np.ndarray


@dataclass(frozen=True, slots=True)
class CampaignProgress:
    """Where a campaign stands after a batch: runs done of all, holds so far, elapsed time."""

    done: int
    total: int
    holds: int
    elapsed_s: float


def _clause_values(
    formula: Any,
    positions: np.ndarray,
    names: Sequence[str],
    dt: float,
    yaw: np.ndarray | None = None,
) -> np.ndarray:
    """Robustness at t = 0 of ``formula`` for every run of ``positions`` ``(R, V, S, 3)``
    (with ``yaw`` ``(R, V, S)``, the headings of the vehicles whose heading ``formula`` reads
    as a fourth signal column, what ``face`` reads).

    Exact and vectorised over runs: the runs' signals are laid end to end and the robustness
    trace is read at each run's first sample.  That is each run's own robustness, because the
    trace at a step reads the signals only over the formula's horizon (``<= S - 1`` steps for
    a formula of the plan), so never past the end of the run's block
    (:mod:`planner.stl.batch` uses the same argument for clause templates).
    """
    n_runs, _, samples, _ = positions.shape
    readers = heading_readers(formula) if yaw is not None else frozenset()
    signals = {}
    for v, n in enumerate(names):
        sig = positions[:, v].reshape(n_runs * samples, 3)
        if n in readers and yaw is not None:
            sig = np.column_stack([sig, yaw[:, v].reshape(n_runs * samples)])
        signals[n] = sig
    trace = formula.robustness_trace(signals, dt)
    return np.asarray(trace[::samples], dtype=float)


def evaluate_batch(plan: Plan, flights: BatchFlights) -> tuple[np.ndarray, ...]:
    """Per run: the spec's robustness (true, reported) and per clause (true, reported), on
    the headings too where the spec reads them (``face``)."""
    phi = plan_formula(plan)
    names = [v.name for v in plan.vehicles]
    dt = plan.check_dt_s
    clauses = phi.clauses
    c_true = np.column_stack(
        [
            _clause_values(c, flights.true_enu_m, names, dt, flights.true_yaw_enu_rad)
            for c in clauses
        ]
    )
    c_rep = np.column_stack(
        [
            _clause_values(c, flights.reported_enu_m, names, dt, flights.reported_yaw_enu_rad)
            for c in clauses
        ]
    )
    return c_true.min(axis=1), c_rep.min(axis=1), c_true, c_rep


def fly_batch(
    plan: Plan,
    setup: SimSetup,
    index: int,
    seeds: Sequence[int],
    dists: Mapping[str, Distribution],
    monitor: MonitorSettings | None = None,
) -> BatchOutcome:
    """Fly and judge one batch of runs (the task a Ray worker runs); with ``monitor``, fly
    them again under the safety monitor."""

    t0 = time.perf_counter()
    flights = simulate(setup, seeds, dists)
    true, rep, c_true, c_rep = evaluate_batch(plan, flights)
    fs = flights.failsafe_s
    first = np.where(np.isnan(fs), np.inf, fs).min(axis=1)  # the run's first failsafe
    first_fs = np.where(np.isinf(first), np.nan, first)
    first_lost = flights.lost_s.min(axis=1)
    first_lost = np.where(np.isinf(first_lost), np.nan, first_lost)
    monitored = None
    replanned = None
    if monitor is not None:
        watched, clause_index = monitor.build(plan)
        again = simulate(setup, seeds, dists, monitor=watched)
        m_true, m_rep, m_c_true, _ = evaluate_batch(plan, again)
        assert again.stop is not None and again.stop_s is not None
        stop_clause = np.where(
            again.stop.clause >= 0, clause_index[np.maximum(again.stop.clause, 0)], -1
        )
        monitored = MonitoredRuns(
            true=m_true,
            reported=m_rep,
            clause_true=m_c_true,
            stop_s=again.stop_s,
            stop_code=again.stop.code,
            stop_clause=stop_clause,
            stop_value=again.stop.value,
        )
        if monitor.replan is not None:
            from gcs.assess.replanned import replan_runs

            replanned = replan_runs(
                plan, monitor.replan, seeds, dists, flights, again, monitor.max_off_plan_m
            )
    return BatchOutcome(
        index=index,
        seeds=flights.seeds,
        true=true,
        reported=rep,
        clause_true=c_true,
        clause_reported=c_rep,
        failsafe_s=first_fs,
        lost_s=first_lost,
        draws={k: (v[:, 0] if v.shape[1] == 1 else v) for k, v in flights.draws.items()},
        sim_s=time.perf_counter() - t0,
        monitored=monitored,
        replanned=replanned,
    )


@dataclass(frozen=True, slots=True)
class MonitorSettings:
    """The safety monitor of a campaign, as ``gcs fly`` sets it up (what a task is sent),
    and how it replans (``None``: it does not)."""

    max_off_plan_m: float | None
    replan: ReplanSettings | None = None

    def build(self, plan: Plan) -> tuple[SafetyMonitor, np.ndarray]:
        """The monitor, and for each of its clauses the index of its top-level clause."""

        phi = plan_formula(plan)
        clauses = always_clauses(phi, [v.name for v in plan.vehicles], reads_heading)
        index = np.array(always_clause_indices(phi, reads_heading), dtype=np.int64)
        return SafetyMonitor(clauses, horizon_s=0.5, max_off_plan_m=self.max_off_plan_m), index


def prepare_campaign(
    plan: Plan, opts: AssessOptions
) -> tuple[SimSetup, dict[str, Distribution], list[int]]:
    """The shared set-up, the distributions and every run's seed (bad input: UserError)."""

    try:
        dists = parse_disturbances(opts.disturbances)
        setup = prepare(
            plan,
            profile=opts.profile,
            params=opts.params,
            rate_hz=opts.rate_hz,
            drag_per_s=opts.drag_per_s,
        )
    except MockConfigError as exc:
        raise UserError(str(exc)) from None
    plan_formula(plan)  # a plan whose spec does not parse fails here, before any run
    seeds = [run_seed(opts.seed, i) for i in range(opts.runs)]
    return setup, dists, seeds


def _batches(seeds: Sequence[int], size: int) -> Iterator[tuple[int, Sequence[int]]]:
    for start in range(0, len(seeds), size):
        yield start, seeds[start : start + size]


def assess(
    plan: Plan,
    opts: AssessOptions,
    *,
    on_batch: Callable[[CampaignProgress], None] | None = None,
) -> AssessResult:
    """Run the campaign and summarise it (see the module docstring).

    ``on_batch`` is called after every finished batch.  A ``KeyboardInterrupt`` stops the
    campaign: the result holds the batches that finished and says it was interrupted.

    Raises:
        UserError: bad options or distributions, an unreachable Ray address.
    """
    setup, dists, seeds = prepare_campaign(plan, opts)
    watch = MonitorSettings(opts.max_off_plan_m, opts.replan) if opts.monitor else None
    t0 = time.perf_counter()
    outcomes: list[BatchOutcome] = []
    interrupted = False

    def got(o: BatchOutcome) -> None:
        outcomes.append(o)
        if on_batch is not None:
            done = sum(len(x.seeds) for x in outcomes)
            holds = sum(int((x.true > 0).sum()) for x in outcomes)
            on_batch(CampaignProgress(done, len(seeds), holds, time.perf_counter() - t0))

    engine = "this process"
    try:
        if opts.workers == 0:
            for start, chunk in _batches(seeds, opts.batch_size):
                got(fly_batch(plan, setup, start, chunk, dists, watch))
        else:
            with ray_session(opts.ray_address, opts.workers) as where:
                engine = where
                for o in _ray_batches(plan, setup, seeds, dists, opts.batch_size, watch):
                    got(o)
    except KeyboardInterrupt:
        interrupted = True
    return summarise(
        plan,
        outcomes,
        opts=opts,
        dists=dists,
        elapsed_s=time.perf_counter() - t0,
        interrupted=interrupted,
        engine=engine,
    )


# ------------------------------------------------------------------------------------- Ray


def _reachable(address: str, timeout_s: float = 3.0) -> bool:
    host, _, port = address.removeprefix("ray://").rpartition(":")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout_s):
            return True
    except (OSError, ValueError):
        return False


@contextlib.contextmanager
def ray_session(address: str | None, workers: int | None) -> Iterator[str]:
    """Ray for one campaign: an existing cluster at ``address`` (or ``RAY_ADDRESS``), or a
    local instance started here with ``workers`` CPUs (``None``: all) and shut down after.

    Yields a description of where the batches run.
    """

    try:
        import ray
    except ImportError:  # pragma: no cover - ray is a dependency
        raise UserError("Ray is not installed: pip install 'ray>=2.40'") from None
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address is not None and address != "auto" and not _reachable(address):
        raise UserError(f"--ray-address {address}: no Ray cluster answers there")
    started_here = not ray.is_initialized()
    if started_here:
        kwargs: dict[str, Any] = {
            "include_dashboard": False,
            "log_to_driver": False,
            "logging_level": logging.ERROR,
        }
        if address is None:
            kwargs["num_cpus"] = workers or os.cpu_count() or 1
        try:
            ray.init(address=address, **kwargs)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise UserError(f"--ray-address {address}: {exc}".splitlines()[0]) from None
    cpus = int(ray.cluster_resources().get("CPU", 0))
    nodes = len([n for n in ray.nodes() if n.get("Alive")])
    where = f"Ray ({nodes} node{'s' if nodes != 1 else ''}, {cpus} CPU{'s' if cpus != 1 else ''})"
    try:
        yield where
    finally:
        if started_here:
            ray.shutdown()


def _batch_task(
    shared: tuple[Plan, SimSetup, Mapping[str, Distribution], MonitorSettings | None],
    index: int,
    seeds: Sequence[int],
) -> BatchOutcome:
    """:func:`fly_batch` as a Ray task: what every batch shares arrives as one object."""
    plan, setup, dists, watch = shared
    return fly_batch(plan, setup, index, seeds, dists, watch)


def _ray_batches(
    plan: Plan,
    setup: SimSetup,
    seeds: Sequence[int],
    dists: Mapping[str, Distribution],
    size: int,
    watch: MonitorSettings | None,
) -> Iterator[BatchOutcome]:
    """Every batch as a Ray task; outcomes as they finish; on interrupt the rest cancelled."""
    import ray

    task = ray.remote(num_cpus=1, max_retries=2)(_batch_task)
    shared: Any = ray.put((plan, setup, dict(dists), watch))  # sent to each node once
    pending = [task.remote(shared, start, list(chunk)) for start, chunk in _batches(seeds, size)]
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield ray.get(ready[0])
    finally:
        for ref in pending:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)


# ---------------------------------------------------------------------------------- replay


def replay(plan: Plan, opts: AssessOptions, seed: int) -> BatchFlights:
    """Fly the run with ``seed`` again, alone: the same disturbances, the same flight (under
    the safety monitor with ``opts.monitor``)."""

    setup, dists, _ = prepare_campaign(plan, dataclasses.replace(opts, runs=1))
    watched = MonitorSettings(opts.max_off_plan_m).build(plan)[0] if opts.monitor else None
    return simulate(setup, [seed], dists, monitor=watched)
