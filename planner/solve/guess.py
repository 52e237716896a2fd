"""The initial guess of :func:`planner.optimize.plan`: timed grid paths through each vehicle's
targets, in lanes, fitted to the limits (``docs/solver-notes.md`` says what each part bought).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.dynamics.limits import vehicle_bounds
from planner.problem import Problem
from planner.solve.path_fit import fit_within_limits
from planner.spec.geometry import Place, keep_out, place
from planner.stl import (
    Always,
    And,
    Formula,
    Implies,
    Not,
    Or,
    Until,
)

# ------------------------------------------------------------------------ initial guess


def _route_length(cursor: np.ndarray, places: Sequence[Place]) -> float:
    pts = [cursor, *(p.point for p in places)]
    return float(sum(np.linalg.norm(b - a) for a, b in itertools.pairwise(pts)))


class Choices:
    """The choices of one vehicle's route (:func:`visit_targets`), in the order they are made:
    each takes the cheapest candidate, or the second cheapest where ``flips`` names it (a
    start of the multi-start, :func:`starts`).  ``regrets`` records what each choice's
    runner-up would have cost more (``inf`` where there is none)."""

    def __init__(self, flips: frozenset[int] = frozenset()) -> None:
        self.flips = flips
        self.regrets: list[float] = []

    def pick(self, costs: Sequence[float]) -> int:
        order = sorted(range(len(costs)), key=lambda j: (costs[j], j))
        index = len(self.regrets)
        second = costs[order[1]] if len(order) > 1 else math.inf
        self.regrets.append(second - costs[order[0]] if math.isfinite(second) else math.inf)
        return order[1] if index in self.flips and math.isfinite(second) else order[0]


def places_in(
    node: Formula,
    vehicle: str,
    cursor: np.ndarray,
    visited: Sequence[Place],
    problem: Problem,
    choices: Choices,
) -> list[Place]:
    """The places ``node`` sends ``vehicle`` to, in the order it visits them (spec order;
    of a disjunction's options the one with the shortest route from ``cursor``, as
    ``choices`` picks).  A place the vehicle is already in (the workspace, a height band, a
    right of way it flies in) or has visited asks it to stay, not to go."""
    if isinstance(node, Not | Implies):
        return []  # what a negation or a condition asks for is not a place to go
    pl = place(node, problem)
    if pl is not None:
        done = pl.contains(cursor) or any(pl.key == q.key for q in visited)
        return [pl] if pl.vehicle == vehicle and not done else []
    if isinstance(node, Or):
        options = [places_in(c, vehicle, cursor, visited, problem, choices) for c in node.operands]
        return options[choices.pick([_route_length(cursor, opt) for opt in options])]
    if isinstance(node, Until):
        ko = keep_out(node.lhs, problem)
        if ko is not None and ko.vehicle == vehicle:
            # "stay out of K until psi": psi's places, reached without entering K
            got = places_in(node.rhs, vehicle, cursor, visited, problem, choices)
            return [dataclasses.replace(pl, clear_of=(*pl.clear_of, ko)) for pl in got]
    out: list[Place] = []
    for child in node.children:
        here = out[-1].point if out else cursor
        out.extend(places_in(child, vehicle, here, [*visited, *out], problem, choices))
    return out


def visit_targets(
    formula: Formula,
    vehicle: str,
    problem: Problem,
    start: np.ndarray,
    choices: Choices | None = None,
) -> list[Place]:
    """The places ``vehicle`` must visit, in visiting order.

    Whatever the spelling (:mod:`planner.spec.geometry`). The clauses of the spec's conjunction
    are visited by deadline (their horizon, earliest first); among clauses with the same
    deadline, and among a disjunction's options, the nearest route from where the vehicle
    is goes first (a greedy tour: "visit one target of each group" picks and orders them;
    an option already visited costs nothing). Inside a clause the spec's order stands
    (nested eventually, until).  ``choices`` may turn any of these choices to its runner-up.
    """
    choices = Choices() if choices is None else choices
    clauses = list(formula.operands) if isinstance(formula, And) else [formula]
    # A clause that does not name the vehicle sends it nowhere; the loop below reads every
    # pending clause once per visit, so the others (reach-avoid N = 16: 120 separation
    # clauses, 1.2 s for nothing) are left out first.
    clauses = [c for c in clauses if vehicle in c.signal_names()]
    pending = sorted(range(len(clauses)), key=lambda i: (clauses[i].horizon, i))
    out: list[Place] = []
    cursor = start
    while pending:
        deadline = clauses[pending[0]].horizon
        due = [i for i in pending if clauses[i].horizon == deadline]
        routes = [places_in(clauses[i], vehicle, cursor, out, problem, choices) for i in due]
        # A route into a place that another pending clause's ``until`` keeps the vehicle
        # out of (until it gets somewhere) waits for that clause.
        held = [
            ko
            for i in pending
            for pl in places_in(clauses[i], vehicle, cursor, out, problem, Choices())
            for ko in pl.clear_of
        ]
        costs = [
            (
                _route_length(cursor, got)
                + _HELD_M * any(ko.contains(p.point) for p in got for ko in held)
            )
            if got
            else math.inf
            for got in routes
        ]
        j = choices.pick(costs) if len(due) > 1 else 0
        pending.remove(due[j])
        out.extend(routes[j])
        if routes[j]:
            cursor = routes[j][-1].point
    return out


#: Extra route length (m) that puts a route into a keep-out of a pending ``until`` last.
_HELD_M = 1e6


def keep_outs_of(formula: Formula, vehicle: str, problem: Problem) -> list[Place]:
    """The places the vehicle must always keep out of (``always`` keep-outs of the spec's
    conjunction, whatever their spelling: :func:`planner.spec.geometry.keep_out`)."""
    out: list[Place] = []

    def walk(node: Formula, always: bool) -> None:
        if always:
            ko = keep_out(node, problem)
            if ko is not None:
                if ko.vehicle == vehicle and all(ko.key != q.key for q in out):
                    out.append(ko)
                return
        if isinstance(node, And):
            for child in node.operands:
                walk(child, always)
        elif isinstance(node, Always):
            walk(node.child, True)

    walk(formula, False)
    return out


def stay_within(formula: Formula, vehicle: str, problem: Problem) -> list[list[Place]]:
    """The unions of places the vehicle must be in at every sample of the whole plan:
    ``always[0, T] (P1 or P2 or ...)`` (or one place) of the spec's conjunction, with ``T``
    the horizon and each option a place of this vehicle, whatever its spelling (stlpy's
    stepping stones, an L-shaped right of way, the workspace).  A window shorter than the
    plan does not bind the whole route and is left to the NLP."""
    horizon = problem.timing.horizon_s
    out: list[list[Place]] = []

    def union(node: Formula) -> list[Place] | None:
        options = list(node.operands) if isinstance(node, Or) else [node]
        places = [place(c, problem) for c in options]
        if any(pl is None or pl.vehicle != vehicle for pl in places):
            return None
        return [pl for pl in places if pl is not None]

    def walk(node: Formula, whole: bool) -> None:
        if whole:
            got = union(node)
            if got is not None:
                out.append(got)
                return
        if isinstance(node, And):
            for child in node.operands:
                walk(child, whole)
        elif isinstance(node, Always) and not whole:
            walk(node.child, node.start_s == 0.0 and node.end_s >= horizon - 1e-9)

    walk(formula, False)
    return out


#: Room (m) a leg keeps from the keep-out of an ``until`` (``phi until psi`` with ``phi`` a
#: keep-out's negation): the least-squares fit to the limits rounds the grid path's corners
#: by about a sample's flight, and a corner taken close ends inside (paddock clearance,
#: climb then cross: -0.39 m with the keep-out as it is, met with 1.5 m of room).
_UNTIL_ROOM_M = 1.5


def _clear_of(later: Sequence[Place]) -> list[Place]:
    """The keep-outs (grown by ``_UNTIL_ROOM_M``) a leg must stay out of because a place it
    leads to, or a later one, is to be reached without entering them (``until``)."""
    out: list[Place] = []
    for pl in later:
        out.extend(ko for ko in pl.clear_of if all(ko.key != q.key for q in out))
    room = _UNTIL_ROOM_M
    return [
        dataclasses.replace(
            ko,
            b=ko.b + room,
            lo_enu_m=tuple(np.subtract(ko.lo_enu_m, room)),
            hi_enu_m=tuple(np.add(ko.hi_enu_m, room)),
        )
        for ko in out
    ]


#: Cells of the initial-guess search grid (at most).
_GRID_CELLS = 40_000


#: Cost factor of a grid step between the places of a stay-within union (in the reach
#: around them): the route crosses gaps where they are narrow and keeps to the places.
_GAP_COST = 3.0


def _grid_graph(
    problem: Problem,
    avoid: Sequence[Any],
    within: Sequence[Sequence[Place]],
    reach: np.ndarray,
    masks: dict[Any, Any] | None,
) -> tuple[np.ndarray, np.ndarray, Any]:
    """:func:`grid_path`'s grid: the cells' centres, which are blocked, and the graph of the
    free cells' 26 neighbours (``masks``: the blocked cells per box, cached)."""
    from scipy.sparse import csr_matrix

    lo = np.asarray(problem.workspace.lo_enu_m)
    hi = np.asarray(problem.workspace.hi_enu_m)
    ext = hi - lo
    feature = min((2.0 * b.depth_m for b in avoid), default=1.0)  # a box: its smallest side
    for pl in (p for u in within for p in u):  # a stay-within place smaller than that
        size = np.subtract(pl.hi_enu_m, pl.lo_enu_m)
        feature = min(feature, float(np.min(size[size > 0], initial=feature)))
    cell = max(feature / 2.0, float((np.prod(ext) / _GRID_CELLS) ** (1 / 3)))
    shape = np.maximum(1, np.floor(ext / cell).astype(int))
    axes = [lo[a] + (np.arange(shape[a]) + 0.5) * ext[a] / shape[a] for a in range(3)]
    cx, cy, cz = np.meshgrid(*axes, indexing="ij")
    centres = np.column_stack([cx.ravel(), cy.ravel(), cz.ravel()])
    step = ext / shape
    blocked = np.zeros(len(centres), dtype=bool)
    grid_key = (tuple(shape), tuple(lo), tuple(hi), feature)
    for b in avoid:  # within half a cell (and 5 % of the feature) of every face
        key = (b, grid_key)  # the box itself (hashed by identity): alive while cached
        mask = None if masks is None else masks.get(key)
        if mask is None:
            grow = 0.5 * step + 0.05 * feature
            mask = np.all(centres @ b.A.T - b.b < np.abs(b.A) @ grow, axis=1)
            if masks is not None:
                masks[key] = mask
        blocked |= mask
    gap = np.zeros(len(centres), dtype=bool)
    for places in within:
        near = np.zeros(len(centres), dtype=bool)
        on = np.zeros(len(centres), dtype=bool)
        for pl in places:
            slack = centres @ pl.A.T - pl.b  # <= 0 inside, per face
            near |= np.all(slack <= np.abs(pl.A) @ reach, axis=1)
            on |= np.all(slack <= 0.0, axis=1)
        blocked |= ~near
        gap |= near & ~on
    idx = np.arange(len(centres)).reshape(shape)
    rows, cols, wts = [], [], []
    for off in (
        np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij")).reshape(3, -1).T
    ):
        if not off.any():
            continue
        src = idx[
            max(0, -off[0]) : shape[0] - max(0, off[0]),
            max(0, -off[1]) : shape[1] - max(0, off[1]),
            max(0, -off[2]) : shape[2] - max(0, off[2]),
        ].ravel()
        dst = src + off[0] * shape[1] * shape[2] + off[1] * shape[2] + off[2]
        ok = ~blocked[src] & ~blocked[dst]
        rows.append(src[ok])
        cols.append(dst[ok])
        cost = np.where(gap[src[ok]] | gap[dst[ok]], _GAP_COST, 1.0)
        wts.append(cost * float(np.linalg.norm(off * step)))
    graph = csr_matrix(
        (np.concatenate(wts), (np.concatenate(rows), np.concatenate(cols))),
        shape=(len(centres), len(centres)),
    )
    return centres, blocked, graph


def grid_path(
    problem: Problem,
    avoid: Sequence[Any],
    points: Sequence[np.ndarray],
    within: Sequence[Sequence[Place]] = (),
    reach_m: np.ndarray | None = None,
    masks: dict[Any, Any] | None = None,
) -> np.ndarray:
    """Shortest polyline through ``points`` (in order) on a voxel grid, around ``avoid``
    boxes and within each of the unions ``within`` (:func:`stay_within`).

    ``masks``: a cache of the cells each avoided box blocks (by box and grid) and of the
    graphs (by what they avoid and stay within), shared by the legs of one initial guess (a
    long line's legs all avoid the same hundred poles: 100 legs of 8 drones along 100 poles
    drew their guess in 27.7 s without it, 7.6 s with the boxes' cells cached).

    A 26-connected grid over the workspace (cell size from the smallest box and a cell
    budget); cells whose centre lies in an avoided box grown by half a cell are blocked, and
    so are those outside a union's places grown by ``reach_m`` (3,) per axis: the exact
    semantics looks at samples, so the path may cross a gap between two places that one
    sample's flight spans, at ``_GAP_COST`` times the length.  Returns (m, 3) vertices;
    falls back to straight segments where no path exists.
    """
    from scipy.sparse.csgraph import dijkstra

    reach = np.zeros(3) if reach_m is None else np.asarray(reach_m, dtype=float)
    key = ("graph", tuple(avoid), tuple(tuple(u) for u in within), tuple(reach))
    got = None if masks is None else masks.get(key)
    if got is None:
        got = _grid_graph(problem, avoid, within, reach, masks)
        if masks is not None:
            masks[key] = got
    centres, blocked, graph = got
    free = np.nonzero(~blocked)[0]
    if free.size == 0:
        return np.asarray(points, dtype=float)

    def nearest(pt: np.ndarray) -> int:
        return int(free[np.argmin(np.linalg.norm(centres[free] - pt, axis=1))])

    out = [np.asarray(points[0], dtype=float)]
    for a, b in itertools.pairwise(points):
        ia, ib = nearest(np.asarray(a)), nearest(np.asarray(b))
        _, pred = dijkstra(graph, indices=ia, return_predecessors=True)
        if ia != ib and pred[ib] < 0:
            out.append(np.asarray(b, dtype=float))
            continue
        chain = [ib]
        while chain[-1] != ia:
            chain.append(int(pred[chain[-1]]))
        out.extend(centres[i] for i in reversed(chain[:-1]))
        out.append(np.asarray(b, dtype=float))
    return np.asarray(out)


#: Fraction of the per-axis limits the initial guess's legs use (the Bezier bounds of the
#: limit constraints are conservative, and the least-squares fit overshoots a little).
_GUESS_LIMIT_FRACTION = 0.75
#: Extra time (s) the guess stays in a target box beyond the spec's hover there.
_GUESS_DWELL_MARGIN_S = 0.75


def hover_times(formula: Formula, vehicle: str, problem: Problem) -> dict[str, float]:
    """Longest ``always[a, b] place`` window (b - a, s) per place of the vehicle (by name)."""
    out: dict[str, float] = {}

    def walk(node: Formula) -> None:
        if isinstance(node, Always):
            pl = place(node.child, problem)
            if pl is not None and pl.vehicle == vehicle:
                out[pl.name] = max(out.get(pl.name, 0.0), node.end_s - node.start_s)
                return
        for child in node.children:
            walk(child)

    walk(formula)
    return out


def axis_limits(vehicle: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(v_max, a_max)`` (3,) per axis that hold both ways (a rest-to-rest leg flies both):
    the slower direction, horizontally the box inside the norm's polygon."""
    (vlo, vhi), (alo, ahi) = (b.box() for b in vehicle_bounds(vehicle))
    return np.minimum(vhi, -vlo), np.minimum(ahi, -alo)


def leg_profile(dist_m: np.ndarray, v_max: np.ndarray, a_max: np.ndarray) -> tuple[float, float]:
    """(duration s, accelerating fraction of it) of the fastest rest-to-rest trapezoidal
    profile over per-axis distances ``dist_m`` (3,) within per-axis ``v_max``/``a_max``.

    Every axis is flown on the same normalised profile; the limiting axis decides.  With
    an accelerating fraction ``phi`` of duration ``T`` the peak speed is ``d / (T (1-phi))``
    and the acceleration ``d / (T^2 phi (1-phi))``.
    """
    d = np.abs(dist_m)
    t_acc = v_max / a_max
    tri = d <= v_max * t_acc  # never reaches v_max
    t = np.where(tri, 2 * np.sqrt(d / a_max), d / v_max + t_acc)
    i = int(np.argmax(t))
    if t[i] <= 0:
        return 0.0, 0.5
    return float(t[i]), float(0.5 if tri[i] else t_acc[i] / t[i])


def _trapezoid_s(t_s: np.ndarray, duration_s: float, phi: float) -> np.ndarray:
    """Normalised path parameter in [0, 1] of a symmetric trapezoidal speed profile that
    accelerates for a fraction ``phi`` (0 < phi <= 0.5) of ``duration_s``."""
    u = np.clip(t_s / max(duration_s, 1e-9), 0.0, 1.0)
    peak = 1.0 / (1.0 - phi)
    acc = peak / phi
    return np.where(
        u < phi,
        0.5 * acc * u**2,
        np.where(u <= 1 - phi, 0.5 * acc * phi**2 + peak * (u - phi), 1 - 0.5 * acc * (1 - u) ** 2),
    )


@dataclass(frozen=True, slots=True)
class Start:
    """One start of the multi-start (:func:`starts`): the route choices of :func:`visit_targets`
    turned to their runner-up (``(vehicle, choice index)``), and a sideways shift (m, left
    of each leg's direction) of every leg of the guess."""

    flips: frozenset[tuple[str, int]] = frozenset()
    offset_m: float = 0.0

    def choices(self, vehicle: str) -> Choices:
        return Choices(frozenset(i for v, i in self.flips if v == vehicle))

    def describe(self, problem: Problem, formula: Formula) -> str:
        """What this start does differently, in words."""
        parts = []
        for name in sorted({v for v, _ in self.flips}):
            x0 = start_of(problem, name)
            route = visit_targets(formula, name, problem, x0, self.choices(name))
            parts.append(f"{name} via " + " -> ".join(pl.name for pl in route))
        if self.offset_m:
            side = "left" if self.offset_m > 0 else "right"
            parts.append(f"legs {abs(self.offset_m):g} m to the {side}")
        return "; ".join(parts) or "the nearest choices, straight legs"


def start_of(problem: Problem, vehicle: str) -> np.ndarray:
    return next(
        np.asarray(v.start_enu_m, dtype=float) for v in problem.vehicles if v.name == vehicle
    )


def starts(problem: Problem, formula: Formula, limit: int) -> Iterator[Start]:
    """The starts of the multi-start, best first, each with a route or a shape none before it
    had (at most ``limit``: ``solver.starts``).

    The first takes the nearest choice everywhere (:func:`visit_targets`). The next ones turn one
    route choice of one vehicle to its runner-up, the choices that cost least extra first
    (another option of a disjunction, another order of clauses), alternating with the first
    route's legs shifted to either side (around a keep-out the other way; off a symmetric
    saddle).  Generated lazily: a plan met by the first start costs nothing here.
    """
    yield Start()
    base: dict[str, tuple[Any, ...]] = {}
    regrets: list[tuple[float, str, int]] = []
    for v in problem.vehicles:
        ch = Choices()
        base[v.name] = _route_key(
            visit_targets(formula, v.name, problem, start_of(problem, v.name), ch)
        )
        regrets.extend((r, v.name, i) for i, r in enumerate(ch.regrets) if math.isfinite(r))
    regrets.sort()
    shift = _shift_m(problem, formula)
    shifts = iter((Start(offset_m=-shift), Start(offset_m=shift)))

    def flips() -> Iterator[Start]:
        seen = {(name, key) for name, key in base.items()}
        for _, name, i in regrets:
            key = _route_key(
                visit_targets(
                    formula, name, problem, start_of(problem, name), Choices(frozenset({i}))
                )
            )
            if (name, key) not in seen:
                seen.add((name, key))
                yield Start(flips=frozenset({(name, i)}))

    given = 1
    sources = [flips(), shifts]
    while given < limit and sources:
        for src in list(sources):
            if given >= limit:
                break
            nxt = next(src, None)
            if nxt is None:
                sources.remove(src)
                continue
            given += 1
            yield nxt


def _route_key(route: Sequence[Place]) -> tuple[Any, ...]:
    return tuple(pl.key for pl in route)


def _shift_m(problem: Problem, formula: Formula) -> float:
    """The sideways shift of the shifted starts: the smallest horizontal half-size of a
    keep-out (at least 1 m), so a leg grazing one passes it on the other side."""
    halves = [
        0.5 * float(np.min(np.subtract(ko.hi_enu_m, ko.lo_enu_m)[:2]))
        if ko.shape[0] == "box"
        else ko.depth_m  # a keep-out turned about the vertical: not its bounding box's
        for v in problem.vehicles
        for ko in keep_outs_of(formula, v.name, problem)
    ]
    return max(1.0, min(halves, default=1.0))


def initial_guess(
    problem: Problem,
    model: Any,
    formula: Formula,
    x0s: list[np.ndarray],
    start: Start | None = None,
) -> np.ndarray:
    """Shortest grid paths through each vehicle's target boxes around the boxes it must
    avoid, fitted to Z by least squares.

    Timing respects the vehicle's limits: each leg (between targets) is flown rest to rest
    with a trapezoidal speed profile (a third accelerating, a third cruising, a third
    braking) along its polyline, no shorter than the per-axis trapezoid time at
    ``_GUESS_LIMIT_FRACTION`` of ``v_max``/``a_max`` over the leg's per-axis travel; at each
    target the vehicle dwells for the spec's hover there (``always[a, b] inside``) plus
    ``_GUESS_DWELL_MARGIN_S``.  The time left over in the horizon is split: half stretches
    the legs (slower is easier on the limits), half lengthens the dwells.  Vehicles sharing
    a target box get points spread along its longest side, so the guess does not put them on
    top of each other.

    ``start`` (default: the first, :class:`Start`) turns some route choices to their
    runner-up and shifts every leg sideways (a start of the multi-start).
    """
    start = Start() if start is None else start
    times = np.asarray(model.times_s)
    horizon = problem.timing.horizon_s
    starts = {v.name: np.asarray(v.start_enu_m, dtype=float) for v in problem.vehicles}
    per_vehicle = {
        v.name: visit_targets(formula, v.name, problem, starts[v.name], start.choices(v.name))
        for v in problem.vehicles
    }
    # Vehicles sent to the same place (the same shape, whoever's predicate names it) share it.
    sharing: dict[Any, list[str]] = {}
    boxes: dict[Any, Place] = {}
    for name, places in per_vehicle.items():
        for pl in places:
            key = pl.shape
            boxes.setdefault(key, pl)
            sharing.setdefault(key, []).append(name)
    sep = float(problem.separation_m or 0.0)
    slots = {key: box_slots(boxes[key], users, starts, sep) for key, users in sharing.items()}

    options: list[list[np.ndarray]] = []
    avoids: list[list[Any]] = []
    masks: dict[Any, Any] = {}  # grid_path's blocked cells and graphs, shared by the legs
    for v in problem.vehicles:
        targets = per_vehicle[v.name]
        pts = [starts[v.name], *(slots[pl.shape][v.name] for pl in targets)]
        avoid = keep_outs_of(formula, v.name, problem)
        avoids.append(avoid)
        if len(pts) == 1:
            options.append([np.tile(pts[0], (len(times), 1))])
            continue
        within = stay_within(formula, v.name, problem)
        reach = 0.5 * axis_limits(v)[0] * problem.timing.check_dt_s
        legs = [
            grid_path(problem, [*avoid, *_clear_of(targets[i:])], [a, b], within, reach, masks)
            for i, (a, b) in enumerate(itertools.pairwise(pts))
        ]
        v_lim, a_lim = (_GUESS_LIMIT_FRACTION * lim for lim in axis_limits(v))
        prof = [leg_profile(np.abs(np.diff(leg, axis=0)).sum(axis=0), v_lim, a_lim) for leg in legs]
        leg_s = np.array([d for d, _ in prof])
        phis = [ph for _, ph in prof]
        hovers = hover_times(formula, v.name, problem)
        dwell_s = np.array([hovers.get(pl.name, 0.0) + _GUESS_DWELL_MARGIN_S for pl in targets])
        slack = horizon - leg_s.sum() - dwell_s.sum()
        if slack > 0:
            leg_s = leg_s + 0.5 * slack * leg_s / max(leg_s.sum(), 1e-9)
            dwell_s = dwell_s + 0.5 * slack / len(dwell_s)
        else:  # infeasible as timed: squeeze everything into the horizon
            scale = horizon / (leg_s.sum() + dwell_s.sum())
            leg_s, dwell_s = leg_s * scale, dwell_s * scale
        options.append(
            [
                _timed_path(
                    times, legs, leg_s, phis, dwell_s, lane * _GUESS_LANE_SEP * sep + start.offset_m
                )
                for lane in _GUESS_LANES
            ]
        )
    # Lanes: a few rounds of each vehicle picking the first lane clear of all the others.
    chosen = [opts[0] for opts in options]
    for _ in range(3):
        changed = False
        for i, opts in enumerate(options):
            others = [p for j, p in enumerate(chosen) if j != i]
            pick = _pick_lane(opts, others, avoids[i], sep)
            changed |= pick is not chosen[i]
            chosen[i] = pick
        if not changed:
            break
    return _fitted(problem, model, x0s, chosen)


def _fitted(
    problem: Problem, model: Any, x0s: list[np.ndarray], paths: Sequence[np.ndarray]
) -> np.ndarray:
    """The flat decision vector of each vehicle's ``path`` (samples on the model's grid,
    ``(n, 3)``) fitted within its limits and the workspace (:func:`fit_within_limits`),
    vehicles in ``problem.vehicles`` order."""
    cols = []
    for path, x0, v in zip(paths, x0s, problem.vehicles, strict=True):
        Zv = fit_within_limits(model, path, x0, v, problem.workspace, problem.timing.end_at_rest)
        cols.append(Zv.reshape(-1, order="F"))
    return np.concatenate(cols)


def box_slots(
    box: Any, users: Sequence[str], starts: Mapping[str, np.ndarray], sep_m: float = 0.0
) -> dict[str, np.ndarray]:
    """Target points for the vehicles sharing ``box``: a k_x x k_y x k_z lattice (the counts
    giving every vehicle its own point with the largest margin), handed out greedily, each
    vehicle taking the free point nearest its start.  A single vehicle gets the centre.

    The margin of a lattice is the smaller of the points' depth inside the box and their
    spacing beyond the separation ``sep_m``, the two robustness terms a vehicle parked there
    is scored by.  Along an axis with ``k > 1`` points both are equal,
    ``m = (ext - sep (k - 1)) / (k + 1)``; an axis with one point puts it mid-box.
    (Reach-avoid, 16 drones in the 0.5 m goal with 0.2 m separation: a 3 x 3 x 2 lattice
    with m = 0.025 m; the cell centres of the same lattice were 0.167 m apart, which
    broke the separation from the start.)
    """
    lo, hi = np.asarray(box.lo_enu_m, dtype=float), np.asarray(box.hi_enu_m, dtype=float)
    ext = hi - lo
    n = len(users)

    def axis_margin(a: int, k: int) -> float:
        return ext[a] / 2 if k == 1 else (ext[a] - sep_m * (k - 1)) / (k + 1)

    best: tuple[float, tuple[int, ...]] = (-np.inf, (1, 1, 1))
    for k in itertools.product(range(1, n + 1), repeat=3):
        if math.prod(k) >= n and math.prod(k) < 2 * n + 2:
            m = min(axis_margin(a, k[a]) for a in range(3))
            if m > best[0] + 1e-12:
                best = (m, k)
    k = best[1]
    axes = []
    for a in range(3):
        if k[a] == 1:
            axes.append(np.array([0.5 * (lo[a] + hi[a])]))
        else:
            m = max(axis_margin(a, k[a]), 0.0)
            axes.append(np.linspace(lo[a] + m, hi[a] - m, k[a]))
    cells = [np.array(c) for c in itertools.product(*axes)]
    out: dict[str, np.ndarray] = {}
    for name in users:
        i = int(np.argmin([np.linalg.norm(c - starts[name]) for c in cells]))
        out[name] = cells.pop(i)
    return out


#: Lateral lanes (multiples of ``_GUESS_LANE_SEP`` x separation) the guess may shift a
#: vehicle's legs into, in order of preference.
_GUESS_LANES = (0, -1, 1, -2, 2, -3, 3)
_GUESS_LANE_SEP = 1.5


def _timed_path(
    times: np.ndarray,
    legs: Sequence[np.ndarray],
    leg_s: np.ndarray,
    phis: Sequence[float],
    dwell_s: np.ndarray,
    lane_m: float,
) -> np.ndarray:
    """Positions (n, 3) at ``times``: each leg flown on its trapezoid, shifted sideways
    (horizontally, left of the leg's direction) by ``lane_m`` away from its two ends."""
    knots_t: list[float] = [0.0]
    knots_p: list[np.ndarray] = [legs[0][0]]
    t_now = 0.0
    for leg, dur, phi, dwell in zip(legs, leg_s, phis, dwell_s, strict=True):
        seg = np.linalg.norm(np.diff(leg, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)]) / max(seg.sum(), 1e-9)
        tt = np.linspace(0.0, dur, 61)[1:]
        arc = _trapezoid_s(tt, dur, phi)
        pos = np.column_stack([np.interp(arc, cum, leg[:, a]) for a in range(3)])
        if lane_m:
            d = leg[-1] - leg[0]
            left = np.array([-d[1], d[0], 0.0])
            norm = float(np.linalg.norm(left))
            if norm > 1e-9:
                u = tt / max(dur, 1e-9)
                bump = np.clip(np.minimum(u, 1 - u) / 0.3, 0.0, 1.0)
                bump = bump * bump * (3 - 2 * bump)
                pos = pos + np.outer(bump, left / norm * lane_m)
        knots_t.extend((t_now + tt).tolist())
        knots_p.extend(pos)
        t_now += dur + dwell
        knots_t.append(t_now)
        knots_p.append(leg[-1])
    poly = np.asarray(knots_p)
    kt = np.asarray(knots_t)
    return np.column_stack([np.interp(times, kt, poly[:, a]) for a in range(3)])


def _pick_lane(
    candidates: Sequence[np.ndarray], placed: Sequence[np.ndarray], avoid: Sequence[Any], sep: float
) -> np.ndarray:
    """The first candidate path clear of the avoided boxes (0.3 m) and 1.3 separations from
    the paths already placed; else the clear one farthest from them."""
    best, best_d = candidates[0], -np.inf
    for path in candidates:
        clear = all(np.all(np.max(path @ b.A.T - b.b, axis=1) >= 0.3) for b in avoid)
        if not clear:
            continue
        d = min((float(np.min(np.linalg.norm(path - q, axis=1))) for q in placed), default=np.inf)
        if d >= 1.3 * sep:
            return path
        if d > best_d:
            best, best_d = path, d
    return best
