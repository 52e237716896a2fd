"""Benchmark: Mueller primitives (generation + input feasibility) and planner matrix build.

Prints a table and then one JSON line. Figures only: nothing here is asserted.

* 10^5 random 3-D primitives (fully defined end state, as in Mueller et al.'s benchmark)
  generated in one vectorised call, then Mueller's recursive thrust / body-rate test on
  all of them (vectorised breadth-first). Mueller, Hehn, D'Andrea (IEEE T-RO 2015) report
  about 10^6 primitives per second (generation and feasibility test) in C++ on a laptop.
* Sample matrices and limit constraints for 16 vehicles, 60 s horizon, 1 s segments,
  Ts = 0.05 s (one MinimumJerkChain per vehicle, as a planner with per-vehicle options
  would build them).

Usage: ``.venv/bin/python benchmarks/bench_primitives.py [--n 100000] [--repeats 3]``
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from planner.dynamics import (
    EndState,
    InputFeasibility,
    InputLimits,
    MinimumJerkChain,
    primitive_coefficients,
    primitive_input_feasibility,
)

MUELLER_RATE_PER_S = 1.0e6


def _best(fn, repeats: int) -> tuple[float, object]:
    best = float("inf")
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    n = args.n
    rng = np.random.default_rng(0)
    # Mueller's benchmark: start at rest, random goal position/velocity/acceleration
    # components, duration 2 s (here also random durations to exercise broadcasting).
    p0 = np.zeros((n, 3))
    v0 = np.zeros((n, 3))
    a0 = np.zeros((n, 3))
    pf = rng.uniform(-2.0, 2.0, (n, 3))
    vf = rng.uniform(-2.0, 2.0, (n, 3))
    af = rng.uniform(-2.0, 2.0, (n, 3))
    T = rng.uniform(1.0, 3.0, (n, 1))
    limits = InputLimits(f_min_m_s2=5.0, f_max_m_s2=30.0, omega_max_rad_s=20.0)

    def generate() -> np.ndarray:
        return primitive_coefficients(p0, v0, a0, pf, vf, af, T, EndState.POS_VEL_ACC)

    t_gen, coeffs = _best(generate, args.repeats)
    t_feas, codes = _best(
        lambda: primitive_input_feasibility(coeffs, T[:, 0], limits, min_section_s=0.02),
        args.repeats,
    )
    counts = np.bincount(np.asarray(codes), minlength=len(InputFeasibility))
    rate_gen = n / t_gen
    rate_both = n / (t_gen + t_feas)

    def build() -> list[MinimumJerkChain]:
        models = [MinimumJerkChain(60.0, 1.0, 0.05) for _ in range(16)]
        for m in models:
            m.limit_constraints(2.0, 3.0)
        return models

    t_build, models = _best(build, args.repeats)
    m0 = models[0]
    cons = m0.limit_constraints(2.0, 3.0)
    mat_bytes = sum(a.nbytes for a in (m0.Mp, m0.Np, m0.Mv, m0.Nv, m0.Ma, m0.Na))

    rows = [
        ("primitives", f"{n}"),
        ("generation time [s]", f"{t_gen:.4f}"),
        ("generation rate [1/s]", f"{rate_gen:,.0f}"),
        ("feasibility time [s]", f"{t_feas:.4f}"),
        ("generation + feasibility rate [1/s]", f"{rate_both:,.0f}"),
        ("ratio to Mueller C++ (1e6/s)", f"{rate_both / MUELLER_RATE_PER_S:.3f}"),
        ("verdicts feas/indet/high/low", "/".join(str(int(c)) for c in counts)),
        ("16 vehicles matrix build [s]", f"{t_build:.4f}"),
        ("per vehicle [ms]", f"{1e3 * t_build / 16:.2f}"),
        ("samples x decisions per vehicle", f"{m0.Mp.shape[0]} x {m0.Mp.shape[1]}"),
        ("limit rows per vehicle (each for 3 axes)", f"{cons.G.shape[0]}"),
        ("sample-matrix memory per vehicle [MB]", f"{mat_bytes / 1e6:.2f}"),
    ]
    width = max(len(k) for k, _ in rows)
    print(f"{'metric':<{width}}  value")
    print("-" * (width + 16))
    for k, v in rows:
        print(f"{k:<{width}}  {v}")
    print(
        json.dumps(
            {
                "bench": "primitives",
                "n_primitives": n,
                "generation_s": t_gen,
                "feasibility_s": t_feas,
                "generation_per_s": rate_gen,
                "generation_and_feasibility_per_s": rate_both,
                "ratio_to_mueller_cpp": rate_both / MUELLER_RATE_PER_S,
                "verdict_counts": {v.name: int(counts[v]) for v in InputFeasibility},
                "matrix_build_16_vehicles_s": t_build,
                "samples": int(m0.Mp.shape[0]),
                "decisions": int(m0.Mp.shape[1]),
                "limit_rows": int(cons.G.shape[0]),
            }
        )
    )


if __name__ == "__main__":
    main()
