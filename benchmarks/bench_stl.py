"""Figures for the STL engine (issue 2): exact robustness scaling and CasADi smooth cost.

1. Exact robustness at t = 0 of
   ``always[0,10] (eventually[0,5] (a >= 0) and ((b >= 0) until[0,20] (c >= 0)))``, dt = 0.01,
   on random traces of 10^4, 10^5 and 10^6 samples (median of repeats), and the same formula
   with every interval doubled. Targets: 10^6 samples < 0.2 s, linear in n, flat in width.
2. Smooth robustness value + gradient through CasADi for a 3-drone reach-avoid formula,
   400 samples per drone (graph build time, instructions, time per call).

Prints a table, then one JSON line. Run: ``.venv/bin/python benchmarks/bench_stl.py``.
"""

from __future__ import annotations

import json
import statistics
import time

import casadi as ca
import numpy as np

from planner.stl import FunctionRegistry, parse

BENCH = "always[0,10] (eventually[0,5] (a >= 0) and ((b >= 0) until[0,20] (c >= 0)))"
BENCH_DOUBLED = "always[0,20] (eventually[0,10] (a >= 0) and ((b >= 0) until[0,40] (c >= 0)))"
DT_S = 0.01


def _median_time_s(fn, repeats: int, clock=time.perf_counter) -> float:
    times = []
    for _ in range(repeats):
        start = clock()
        fn()
        times.append(clock() - start)
    return statistics.median(times)


def exact_figures() -> list[dict]:
    rng = np.random.default_rng(0)
    rows = []
    for label, text in (("base", BENCH), ("doubled", BENCH_DOUBLED)):
        phi = parse(text)
        for n in (10_000, 100_000, 1_000_000):
            signals = {name: rng.normal(size=n) for name in "abc"}
            repeats = 7 if n < 1_000_000 else 5
            phi.robustness(signals, DT_S)  # warm-up
            run = lambda: phi.robustness(signals, DT_S)  # noqa: B023, E731
            t_s = _median_time_s(run, repeats)
            # CPU time of this process: less inflated than wall time on a shared machine.
            cpu_s = _median_time_s(run, repeats, time.process_time)
            rows.append(
                {
                    "intervals": label,
                    "n": n,
                    "time_s": t_s,
                    "cpu_s": cpu_s,
                    "ns_per_sample": 1e9 * t_s / n,
                }
            )
    return rows


# --------------------------------------------------------------------------- reach-avoid

BOXES = {
    "goal1": ((8.0, 8.0, 2.0), (10.0, 10.0, 4.0)),
    "goal2": ((8.0, -10.0, 2.0), (10.0, -8.0, 4.0)),
    "goal3": ((-10.0, 8.0, 2.0), (-8.0, 10.0, 4.0)),
    "obs1": ((2.0, 2.0, 0.0), (4.0, 4.0, 10.0)),
    "obs2": ((-4.0, -1.0, 0.0), (-2.0, 1.0, 10.0)),
    "work": ((-12.0, -12.0, 0.5), (12.0, 12.0, 8.0)),
}
REACH_AVOID = " and ".join(
    [f"eventually[20,35] always[0,2] inside(d{i}, goal{i})" for i in (1, 2, 3)]
    + [
        f"always[0,39.9] (inside(d{i}, work) and outside(d{i}, obs1) and outside(d{i}, obs2))"
        for i in (1, 2, 3)
    ]
    + [f"always[0,39.9] (dist(d{i}, d{j}) >= 1)" for i, j in ((1, 2), (1, 3), (2, 3))]
)


def _margins_ca(pos, box):
    lo, hi = (ca.repmat(ca.DM(v).T, pos.shape[0], 1) for v in BOXES[box])
    m = ca.fmin(pos - lo, hi - pos)
    return ca.fmin(ca.fmin(m[:, 0], m[:, 1]), m[:, 2])


def _margins_np(pos, box):
    lo, hi = (np.array(v) for v in BOXES[box])
    return np.minimum(pos - lo, hi - pos).min(axis=1)


def reach_avoid_registry() -> FunctionRegistry:
    reg = FunctionRegistry()
    reg.register(
        "inside",
        2,
        lambda a, s: _margins_np(s[a[0]], a[1]),
        lambda a, s: _margins_ca(s[a[0]], a[1]),
        signal_args=(0,),
    )
    reg.register(
        "outside",
        2,
        lambda a, s: -_margins_np(s[a[0]], a[1]),
        lambda a, s: -_margins_ca(s[a[0]], a[1]),
        signal_args=(0,),
    )
    reg.register(
        "dist",
        2,
        lambda a, s: np.linalg.norm(s[a[0]] - s[a[1]], axis=1),
        lambda a, s: ca.sqrt(ca.sum2((s[a[0]] - s[a[1]]) ** 2) + 1e-12),
        signal_args=(0, 1),
    )
    return reg


def casadi_figures(n: int = 400, dt_s: float = 0.1, k: float = 10.0) -> dict:
    phi = parse(REACH_AVOID, reach_avoid_registry())
    syms = {f"d{i}": ca.SX.sym(f"d{i}", n, 3) for i in (1, 2, 3)}
    flat = ca.vertcat(*(ca.vec(s) for s in syms.values()))
    start = time.perf_counter()
    rho = phi.smooth_robustness(syms, dt_s, k)
    fun = ca.Function("rho_grad", [flat], [rho, ca.gradient(rho, flat)])
    build_s = time.perf_counter() - start
    rng = np.random.default_rng(1)
    x = rng.uniform(-10, 10, size=flat.shape[0])
    fun(x)
    call_s = _median_time_s(lambda: fun(x), 200)
    value = float(fun(x)[0])
    sig = {name: x[i * 3 * n : (i + 1) * 3 * n].reshape(3, n).T for i, name in enumerate(syms)}
    numpy_value = phi.smooth_robustness(sig, dt_s, k)
    return {
        "samples_per_drone": n,
        "decision_vars": int(flat.shape[0]),
        "build_s": build_s,
        "instructions": int(fun.n_instructions()),
        "value_grad_call_s": call_s,
        "numpy_vs_casadi_abs_diff": abs(value - numpy_value),
    }


def main() -> None:
    rows = exact_figures()
    print("Exact robustness, dt = 0.01 s:", BENCH)
    print(f"{'intervals':<10}{'n':>10}{'median wall':>14}{'median CPU':>14}{'ns/sample':>12}")
    for row in rows:
        print(
            f"{row['intervals']:<10}{row['n']:>10}{row['time_s'] * 1e3:>11.1f} ms"
            f"{row['cpu_s'] * 1e3:>11.1f} ms{row['ns_per_sample']:>12.1f}"
        )
    ra = casadi_figures()
    print()
    print("Smooth robustness + gradient through CasADi, 3-drone reach-avoid, k = 10:")
    print(f"  samples per drone          {ra['samples_per_drone']}")
    print(f"  decision variables         {ra['decision_vars']}")
    print(f"  graph build (expr + grad)  {ra['build_s'] * 1e3:.1f} ms")
    print(f"  SX instructions            {ra['instructions']}")
    print(f"  value + gradient per call  {ra['value_grad_call_s'] * 1e6:.0f} us")
    print(f"  |numpy - CasADi| value     {ra['numpy_vs_casadi_abs_diff']:.2e}")
    print(json.dumps({"bench": "stl", "exact": rows, "reach_avoid_casadi": ra}))


if __name__ == "__main__":
    main()
