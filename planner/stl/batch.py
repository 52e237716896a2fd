"""Many clauses evaluated at once: clauses that differ only in the signals they read share one
evaluation.

A specification over a fleet repeats a few clause *templates* over vehicles and pairs of
vehicles (``each: d in all``, ``each: (a, b) in pairs(all)``): 64 vehicles give 2,016
separation clauses that are the same formula on different signals. Evaluating them one by one
costs a Python walk of the formula each; here each template is evaluated once, on its
bindings' signals laid end to end.

That is exact. A clause's robustness at step ``t`` reads its signals only on
``[t, t + H]`` (``H`` its horizon in steps), so with each binding's ``S`` samples as one block
of the concatenated signals and ``H <= S - 1``, the trace at a block's first step is the
clause's robustness on that binding alone, and for an atemporal template (``H = 0``) the whole
block is the binding's trace (``planner.stl.exact``: every operator is exact wherever its
horizon fits, whatever lies beyond it).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from planner.stl.ast import Call, Expr, Formula, Signal


def signal_order(node: Formula | Expr) -> tuple[str, ...]:
    """The signal names ``node`` reads, in the order they first appear (left to right)."""
    seen: dict[str, None] = {}

    def visit(n: Any) -> None:
        if isinstance(n, Call):
            sig = n.function.signal_names(n.args)
            for a in n.args:
                if a in sig:
                    seen.setdefault(a, None)
            return
        if isinstance(n, Signal):
            seen.setdefault(n.name, None)
            return
        for f in dataclasses.fields(n):
            value = getattr(n, f.name)
            if isinstance(value, Formula | Expr):
                visit(value)
            elif isinstance(value, tuple):
                for x in value:
                    if isinstance(x, Formula | Expr):
                        visit(x)

    visit(node)
    return tuple(seen)


def rename_signals(node: Any, mapping: Mapping[str, str]) -> Any:
    """``node`` with its signals renamed by ``mapping`` (other identifiers kept)."""
    if isinstance(node, Call):
        sig = node.function.signal_names(node.args)
        args = tuple(mapping.get(a, a) if a in sig else a for a in node.args)
        return node if args == node.args else dataclasses.replace(node, args=args)
    if isinstance(node, Signal):
        return dataclasses.replace(node, name=mapping.get(node.name, node.name))
    changes: dict[str, Any] = {}
    for f in dataclasses.fields(node):
        value = getattr(node, f.name)
        if isinstance(value, Formula | Expr):
            changes[f.name] = rename_signals(value, mapping)
        elif isinstance(value, tuple) and any(isinstance(x, Formula | Expr) for x in value):
            changes[f.name] = tuple(
                rename_signals(x, mapping) if isinstance(x, Formula | Expr) else x for x in value
            )
    return dataclasses.replace(node, **changes) if changes else node


@dataclasses.dataclass(frozen=True, slots=True, eq=False)
class _Group:
    template: Formula
    horizon_steps_at: Any  # dt -> steps, the template's horizon
    members: np.ndarray  # (K,) clause indices
    bindings: tuple[tuple[str, ...], ...]  # (K, J) signal names, the template's _s0.._sJ


class ClauseBatch:
    """Robustness of ``clauses`` on shared signals, one evaluation per template.

    Args:
        clauses: formulas over signals of one shape (e.g. ``(S, 3)`` positions per vehicle).

    Attributes:
        templates: how many distinct templates the clauses make (each one evaluation).
    """

    def __init__(self, clauses: Sequence[Formula]) -> None:
        self.clauses = tuple(clauses)
        groups: dict[Formula, list[tuple[int, tuple[str, ...]]]] = {}
        for i, clause in enumerate(self.clauses):
            names = signal_order(clause)
            template = rename_signals(clause, {n: f"_s{j}" for j, n in enumerate(names)})
            groups.setdefault(template, []).append((i, names))
        self._groups = tuple(
            _Group(
                template,
                template.horizon_steps,
                np.array([i for i, _ in members], dtype=int),
                tuple(names for _, names in members),
            )
            for template, members in groups.items()
        )
        self.templates = len(self._groups)
        self._slot_cache: dict[tuple[str, ...], list[tuple[_Group, list[np.ndarray]]] | None] = {}

    def _slots(self, names: tuple[str, ...]) -> list[tuple[_Group, list[np.ndarray]]] | None:
        """Per template, per signal slot, the rows of ``names`` its bindings read (cached per
        ``names``); ``None`` if a binding reads a signal not in ``names``."""
        cached = self._slot_cache.get(names)
        if cached is not None or names in self._slot_cache:
            return cached
        row = {n: k for k, n in enumerate(names)}
        out: list[tuple[_Group, list[np.ndarray]]] = []
        for g in self._groups:
            j_count = len(g.bindings[0])
            try:
                idx = [np.array([row[b[j]] for b in g.bindings], dtype=int) for j in range(j_count)]
            except KeyError:
                self._slot_cache[names] = None
                return None
            out.append((g, idx))
        self._slot_cache[names] = out
        return out

    def values_of(self, stack: np.ndarray, names: tuple[str, ...], dt: float) -> np.ndarray:
        """:meth:`values` of signals given stacked: ``stack[k]`` is the signal ``names[k]``
        (all of one shape ``(S, ...)``)."""
        slots = self._slots(names)
        if slots is None:
            return self.values(dict(zip(names, stack, strict=True)), dt)
        rows = stack.shape[1]
        out = np.empty(len(self.clauses))
        for g, idx in slots:
            if g.horizon_steps_at(dt) > rows - 1 or not idx:
                view = dict(zip(names, stack, strict=True))
                for i in g.members:
                    out[i] = self.clauses[i].robustness(view, dt)
                continue
            sig = {f"_s{j}": _flat(stack[ix]) for j, ix in enumerate(idx)}
            trace = np.asarray(g.template.robustness_trace(sig, dt), dtype=float)
            out[g.members] = trace[::rows][: len(g.members)]
        return out

    def traces_of(self, stack: np.ndarray, names: tuple[str, ...], dt: float) -> np.ndarray:
        """:meth:`traces` of signals given stacked (see :meth:`values_of`)."""
        slots = self._slots(names)
        if slots is None:
            return self.traces(dict(zip(names, stack, strict=True)), dt)
        rows = stack.shape[1]
        out = np.empty((len(self.clauses), rows))
        for g, idx in slots:
            if g.horizon_steps_at(dt) != 0:
                raise ValueError(f"traces() takes atemporal clauses; {g.template} is temporal")
            if not idx:
                view = dict(zip(names, stack, strict=True))
                for i in g.members:
                    out[i] = self.clauses[i].robustness_trace(view, dt)[:rows]
                continue
            sig = {f"_s{j}": _flat(stack[ix]) for j, ix in enumerate(idx)}
            trace = np.asarray(g.template.robustness_trace(sig, dt))
            out[g.members] = trace.reshape(len(g.members), rows)
        return out

    def values(self, signals: Mapping[str, np.ndarray], dt: float) -> np.ndarray:
        """``(len(clauses),)`` robustness of every clause at t = 0 (as ``clause.robustness``).

        Every signal a clause reads needs the same number of samples ``S``; a template whose
        horizon does not fit in them is evaluated clause by clause (as the clause itself
        would be, error included).
        """
        stacked = _stack(signals)
        if stacked is not None:
            return self.values_of(stacked, tuple(signals), dt)
        out = np.empty(len(self.clauses))
        for g in self._groups:
            rows = _rows(signals, g.bindings)
            if g.horizon_steps_at(dt) > rows - 1 or len(g.bindings[0]) == 0:
                for i in g.members:
                    out[i] = self.clauses[i].robustness(signals, dt)
                continue
            trace = g.template.robustness_trace(_concat(g, signals, rows), dt)
            out[g.members] = np.asarray(trace, dtype=float)[::rows][: len(g.members)]
        return out

    def traces(self, signals: Mapping[str, np.ndarray], dt: float) -> np.ndarray:
        """``(len(clauses), S)`` robustness traces of atemporal clauses (``S`` samples each)."""
        stacked = _stack(signals)
        if stacked is not None:
            return self.traces_of(stacked, tuple(signals), dt)
        rows = _rows(signals, tuple(b for g in self._groups for b in g.bindings))
        out = np.empty((len(self.clauses), rows))
        for g in self._groups:
            if g.horizon_steps_at(dt) != 0:
                raise ValueError(f"traces() takes atemporal clauses; {g.template} is temporal")
            if len(g.bindings[0]) == 0:
                for i in g.members:
                    out[i] = self.clauses[i].robustness_trace(signals, dt)[:rows]
                continue
            trace = np.asarray(g.template.robustness_trace(_concat(g, signals, rows), dt))
            out[g.members] = trace.reshape(len(g.members), rows)
        return out


def _flat(block: np.ndarray) -> np.ndarray:
    """``(K, S, ...)`` -> ``(K * S, ...)``: the bindings' signals end to end."""
    return block.reshape(block.shape[0] * block.shape[1], *block.shape[2:])


def _stack(signals: Mapping[str, np.ndarray]) -> np.ndarray | None:
    """The signals as one ``(len, S, ...)`` array, or ``None`` if their shapes differ."""
    arrays = [np.asarray(a) for a in signals.values()]
    if not arrays or any(a.shape != arrays[0].shape for a in arrays):
        return None
    return np.stack(arrays)


def _concat(g: _Group, signals: Mapping[str, np.ndarray], rows: int) -> dict[str, np.ndarray]:
    return {
        f"_s{j}": np.concatenate([np.asarray(signals[b[j]])[:rows] for b in g.bindings])
        for j in range(len(g.bindings[0]))
    }


def _rows(signals: Mapping[str, np.ndarray], bindings: Sequence[tuple[str, ...]]) -> int:
    """The common sample count of the signals ``bindings`` read (ValueError if they differ)."""
    counts = {len(signals[name]) for b in bindings for name in b}
    if len(counts) > 1:
        raise ValueError(f"signals of different lengths: {sorted(counts)}")
    return counts.pop() if counts else 1
