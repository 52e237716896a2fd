"""A sparse mixed-integer linear program assembled in blocks of rows, solved by HiGHS.

Rows are added many at a time as dense ``(m, k)`` blocks of column indices and coefficients
(:meth:`MilpBuilder.add_rows`), so an encoding builds a whole window of an STL operator in
one numpy call instead of one Python call per row; the blocks are joined into one CSR matrix
only when the program is handed to HiGHS (:meth:`MilpBuilder.solve`).
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["HighsOutcome", "MilpBuilder"]

IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class HighsOutcome:
    """What HiGHS returned.

    Attributes:
        status: HiGHS's model status, by name (``"kOptimal"``, ``"kTimeLimit"``, ...).
        has_solution: whether a primal feasible point (an incumbent) exists.
        objective: its objective value (nan without one).
        bound: HiGHS's best bound on the objective (its dual bound; inf when unknown).
        x: the column values, shape (num_cols,) (empty without a solution).
        setup_s: wall time to assemble the matrix and pass it to HiGHS.
        solve_s: wall time of ``run()``.
        nodes: branch-and-bound nodes.
    """

    status: str
    has_solution: bool
    objective: float
    bound: float
    x: FloatArray
    setup_s: float
    solve_s: float
    nodes: int


class MilpBuilder:
    """Columns, rows and an objective to maximise, added in vectorised blocks."""

    def __init__(self) -> None:
        self._lb: list[FloatArray] = []
        self._ub: list[FloatArray] = []
        self._int: list[NDArray[np.bool_]] = []
        self.num_cols = 0
        self._rows_cols: list[IntArray] = []
        self._rows_vals: list[FloatArray] = []
        self._rows_ptr: list[IntArray] = []
        self._row_lo: list[FloatArray] = []
        self._row_hi: list[FloatArray] = []
        self.num_rows = 0
        self._nnz = 0
        self.cost: dict[int, float] = {}

    # ---- columns

    def add_vars(
        self, n: int, lb: ArrayLike = -math.inf, ub: ArrayLike = math.inf, integer: bool = False
    ) -> IntArray:
        """Add ``n`` columns with bounds (scalars or (n,) arrays); returns their indices (n,)."""
        self._lb.append(np.broadcast_to(np.asarray(lb, dtype=float), (n,)).copy())
        self._ub.append(np.broadcast_to(np.asarray(ub, dtype=float), (n,)).copy())
        self._int.append(np.full(n, integer))
        idx = np.arange(self.num_cols, self.num_cols + n, dtype=np.int64)
        self.num_cols += n
        return idx

    def add_binaries(self, n: int) -> IntArray:
        """Add ``n`` 0/1 columns."""
        return self.add_vars(n, 0.0, 1.0, integer=True)

    def set_bounds(self, cols: ArrayLike, lb: ArrayLike, ub: ArrayLike) -> None:
        """Overwrite the bounds of existing columns (e.g. fix the start positions)."""
        lo, hi = np.concatenate(self._lb), np.concatenate(self._ub)
        c = np.asarray(cols, dtype=np.int64)
        lo[c], hi[c] = lb, ub
        self._lb, self._ub = [lo], [hi]
        self._int = [np.concatenate(self._int)]

    # ---- rows

    def add_rows(
        self, cols: ArrayLike, vals: ArrayLike, lo: ArrayLike = -math.inf, hi: ArrayLike = math.inf
    ) -> None:
        """Add ``m`` rows ``lo <= sum_k vals[i, k] x[cols[i, k]] <= hi``.

        Args:
            cols: (m, k) column indices; a column repeated in a row adds up.
            vals: (m, k) coefficients (zeros allowed: they are dropped).
            lo, hi: scalars or (m,) arrays.
        """
        c = np.asarray(cols, dtype=np.int64)
        v = np.asarray(vals, dtype=float)
        if c.ndim != 2 or c.shape != v.shape:
            raise ValueError(f"rows need (m, k) cols and vals alike, got {c.shape} and {v.shape}")
        m, k = c.shape
        if m == 0:
            return
        self._rows_cols.append(c.reshape(-1))
        self._rows_vals.append(v.reshape(-1))
        self._rows_ptr.append(self._nnz + k * np.arange(m, dtype=np.int64))
        self._row_lo.append(np.broadcast_to(np.asarray(lo, dtype=float), (m,)).copy())
        self._row_hi.append(np.broadcast_to(np.asarray(hi, dtype=float), (m,)).copy())
        self.num_rows += m
        self._nnz += m * k

    def integer_columns(self) -> IntArray:
        """Indices of the integer columns."""
        if not self._int:
            return np.zeros(0, dtype=np.int64)
        return np.flatnonzero(np.concatenate(self._int)).astype(np.int64)

    @property
    def num_integers(self) -> int:
        """How many integer columns."""
        return int(sum(int(a.sum()) for a in self._int))

    # ---- solve

    def solve(
        self,
        *,
        time_limit_s: float,
        mip_rel_gap: float = 1e-4,
        stop: threading.Event | None = None,
        on_incumbent: Callable[[float], None] | None = None,
        cpu_until: float | None = None,
    ) -> HighsOutcome:
        """Maximise ``sum cost[j] x[j]`` with HiGHS (one thread, quiet) under a time limit;
        ``stop``: once set (from another thread), HiGHS ends at its next interrupt check with
        the incumbent it has (status ``kInterrupt``); ``on_incumbent``: called (in HiGHS's
        thread) with the objective of each better incumbent HiGHS finds; ``cpu_until``: HiGHS
        also stops (status ``kTimeLimit``) once the calling thread's CPU time
        (``time.thread_time()``) passes this: a budget of work that does not shrink when the
        thread shares its cores."""
        import highspy
        from scipy.sparse import csr_matrix

        t_setup = time.perf_counter()
        lp = highspy.HighsLp()
        lp.num_col_ = self.num_cols
        lp.num_row_ = self.num_rows
        cost = np.zeros(self.num_cols)
        for j, c in self.cost.items():
            cost[j] += c
        lp.col_cost_ = cost
        lp.col_lower_ = np.concatenate(self._lb) if self._lb else np.zeros(0)
        lp.col_upper_ = np.concatenate(self._ub) if self._ub else np.zeros(0)
        lp.sense_ = highspy.ObjSense.kMaximize
        if self.num_rows:
            cols = np.concatenate(self._rows_cols)
            vals = np.concatenate(self._rows_vals)
            starts = np.concatenate([*self._rows_ptr, [self._nnz]])
            # rows hold k entries each; csr_matrix sums repeats and the eliminate_zeros drops
            # the padding of rows that use fewer entries than their block's width
            a = csr_matrix((vals, cols, starts), shape=(self.num_rows, self.num_cols))
            a.sum_duplicates()
            a.eliminate_zeros()
            lp.row_lower_ = np.concatenate(self._row_lo)
            lp.row_upper_ = np.concatenate(self._row_hi)
            lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
            lp.a_matrix_.num_col_ = self.num_cols
            lp.a_matrix_.num_row_ = self.num_rows
            lp.a_matrix_.start_ = a.indptr.astype(np.int32)
            lp.a_matrix_.index_ = a.indices.astype(np.int32)
            lp.a_matrix_.value_ = a.data
        integer = np.concatenate(self._int) if self._int else np.zeros(0, dtype=bool)
        if integer.any():
            lp.integrality_ = [
                highspy.HighsVarType.kInteger if i else highspy.HighsVarType.kContinuous
                for i in integer
            ]
        # One HiGHS at a time in the process: two instances running in two threads share
        # its task scheduler and corrupt the heap (a plan's combinatorial stage runs in a
        # thread; two plans in two threads crashed in a few runs without this lock)
        while not _HIGHS_LOCK.acquire(timeout=0.05):
            waited = time.perf_counter() - t_setup
            if (stop is not None and stop.is_set()) or waited >= time_limit_s:
                why = "kInterrupt" if stop is not None and stop.is_set() else "kTimeLimit"
                return HighsOutcome(why, False, math.nan, math.inf, np.zeros(0), waited, 0.0, 0)
        try:
            return self._run(highspy, lp, integer, t_setup, time_limit_s, mip_rel_gap,
                             stop, on_incumbent, cpu_until)  # fmt: skip
        finally:
            _HIGHS_LOCK.release()

    def _run(
        self,
        highspy: Any,
        lp: Any,
        integer: np.ndarray,
        t_setup: float,
        time_limit_s: float,
        mip_rel_gap: float,
        stop: threading.Event | None,
        on_incumbent: Callable[[float], None] | None,
        cpu_until: float | None,
    ) -> HighsOutcome:
        h = _quiet_highs(highspy)
        h.setOptionValue("output_flag", False)
        h.setOptionValue("threads", 1)
        h.setOptionValue("time_limit", max(float(time_limit_s), 1e-3))
        h.setOptionValue("mip_rel_gap", float(mip_rel_gap))
        # tight feasibility: a big-M row with a binary at 1 - 1e-6 must not lift r by M 1e-6
        h.setOptionValue("mip_feasibility_tolerance", 1e-9)
        h.setOptionValue("primal_feasibility_tolerance", 1e-9)
        # Presolve off: on the zoo's programs HiGHS's presolve cost more than it saved
        # (solve_coarse to optimal, one thread, presolve on -> off: the allocation mission
        # 19.8 -> 3.7 s and 1,414 nodes -> 1; door puzzle 8.0 -> 5.3 s; multitarget
        # 15.6 -> 8.5 s; mutual exclusion 5.2 -> 3.3 s; stepping stones 1.0 -> 1.7 s)
        h.setOptionValue("presolve", "off")
        h.passModel(lp)
        out_of_cpu = False
        if stop is not None or cpu_until is not None:

            def interrupt(event: Any) -> None:
                nonlocal out_of_cpu
                if stop is not None and stop.is_set():
                    event.interrupt()
                elif cpu_until is not None and time.thread_time() > cpu_until:
                    out_of_cpu = True
                    event.interrupt()

            h.cbSimplexInterrupt += interrupt
            h.cbMipInterrupt += interrupt
        if on_incumbent is not None:

            def improved(event: Any) -> None:
                on_incumbent(float(event.data_out.objective_function_value))

            h.cbMipImprovingSolution += improved
        t0 = time.perf_counter()
        setup_s = t0 - t_setup
        h.setOptionValue("time_limit", max(float(time_limit_s) - setup_s, 1e-3))
        h.run()
        solve_s = time.perf_counter() - t0
        info = h.getInfo()
        has = int(info.primal_solution_status) == 2  # kSolutionStatusFeasible
        x = np.asarray(h.getSolution().col_value, dtype=float) if has else np.zeros(0)
        obj = float(info.objective_function_value) if has else math.nan
        bound = float(info.mip_dual_bound) if integer.any() else obj
        name = str(h.getModelStatus()).rsplit(".", 1)[-1]
        if name == "kInterrupt" and out_of_cpu:
            name = "kTimeLimit"  # the budget of CPU time
        return HighsOutcome(
            status=name,
            has_solution=has,
            objective=obj,
            bound=bound,
            x=x,
            setup_s=setup_s,
            solve_s=solve_s,
            nodes=int(info.mip_node_count) if integer.any() else 0,
        )


#: Whether HiGHS has printed its banner in this process (it does so once, at the first
#: ``Highs()``, before any option can silence it).
_BANNER_DONE = threading.Event()


def _quiet_highs(highspy: Any) -> Any:
    """A ``highspy.Highs()`` whose first construction in the process writes its copyright
    banner to /dev/null instead of standard output (``gcs plan --json`` prints JSON there)."""
    if _BANNER_DONE.is_set():
        return highspy.Highs()
    with _BANNER_LOCK:
        sys.stdout.flush()
        saved = os.dup(1)
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, 1)
            h = highspy.Highs()
        finally:
            os.dup2(saved, 1)
            os.close(saved)
            os.close(devnull)
        _BANNER_DONE.set()
    return h


_BANNER_LOCK = threading.Lock()
#: Held while a HiGHS instance exists and runs (:meth:`MilpBuilder.solve`).
_HIGHS_LOCK = threading.Lock()
