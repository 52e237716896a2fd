"""Checking and normalising the ``signals`` mapping (numpy or CasADi).

Numpy signals: 1-D arrays (n,) for scalars ((n, 1) is accepted and flattened), (n, d) for
vectors; float64, finite. CasADi signals: SX or MX matrices (n, 1) / (n, d); numpy arrays may be
mixed in and are converted to DM. All signals share the same n.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import Any

import numpy as np

from planner.stl.errors import SignalShapeError


def _symbolic() -> tuple[type, ...]:
    """CasADi's SX and MX, if CasADi is loaded (no value can be one otherwise: the exact
    semantics never import CasADi)."""
    ca = sys.modules.get("casadi")
    return () if ca is None else (ca.SX, ca.MX)


def is_symbolic(signals: Mapping[str, Any]) -> bool:
    """True when any signal is a CasADi SX/MX matrix."""
    kinds = _symbolic()
    return bool(kinds) and any(isinstance(value, kinds) for value in signals.values())


def numpy_signals(signals: Mapping[str, Any]) -> tuple[dict[str, np.ndarray], int]:
    """Signals as float64 arrays, and their common length n.

    Raises:
        SignalShapeError: empty mapping, non-numeric, wrong dimensions, unequal lengths,
            NaN/inf values, or CasADi symbols (exact robustness needs numbers).
    """
    if not isinstance(signals, Mapping):
        raise SignalShapeError(f"signals must be a mapping name -> array, got {type(signals)}")
    if not signals:
        raise SignalShapeError("no signals given: cannot tell the trace length")
    out: dict[str, np.ndarray] = {}
    n: int | None = None
    first = ""
    symbolic = _symbolic()
    for name, value in signals.items():
        if symbolic and isinstance(value, symbolic):
            raise SignalShapeError(
                f"signal {name!r} is a CasADi symbol: exact robustness needs numeric signals"
            )
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise SignalShapeError(f"signal {name!r} is not numeric: {exc}") from exc
        if array.ndim == 2 and array.shape[1] == 1:
            array = array[:, 0]
        if array.ndim not in (1, 2):
            raise SignalShapeError(
                f"signal {name!r} has shape {array.shape}; expected (n,) or (n, d)"
            )
        if n is None:
            n, first = array.shape[0], name
        elif array.shape[0] != n:
            raise SignalShapeError(
                f"signal {name!r} has {array.shape[0]} samples but {first!r} has {n}"
            )
        finite = np.isfinite(array)
        if not finite.all():
            bad = int(np.argwhere(~finite)[0][0])
            raise SignalShapeError(f"signal {name!r} is not finite at sample {bad}")
        out[name] = array
    assert n is not None
    return out, n


def casadi_signals(signals: Mapping[str, Any]) -> tuple[dict[str, Any], int, type]:
    """Signals as CasADi matrices (n, d), their common length n and the symbol type (SX/MX).

    Raises:
        SignalShapeError: SX mixed with MX, wrong dimensions, unequal lengths.
    """
    import casadi as ca

    symbolic = (ca.SX, ca.MX)
    kinds = {type(v) for v in signals.values() if isinstance(v, symbolic)}
    if len(kinds) != 1:
        raise SignalShapeError(f"signals mix CasADi types {sorted(k.__name__ for k in kinds)}")
    kind = kinds.pop()
    out: dict[str, Any] = {}
    n: int | None = None
    first = ""
    for name, value in signals.items():
        if isinstance(value, (*symbolic, ca.DM)):
            matrix = value
        else:
            try:
                array = np.asarray(value, dtype=float)
            except (TypeError, ValueError) as exc:
                raise SignalShapeError(f"signal {name!r} is not numeric: {exc}") from exc
            if array.ndim == 1:
                array = array[:, None]
            if array.ndim != 2:
                raise SignalShapeError(
                    f"signal {name!r} has shape {array.shape}; expected (n, 1) or (n, d)"
                )
            matrix = ca.DM(array)
        rows = matrix.shape[0]
        if n is None:
            n, first = rows, name
        elif rows != n:
            raise SignalShapeError(f"signal {name!r} has {rows} samples but {first!r} has {n}")
        out[name] = matrix
    assert n is not None
    return out, n, kind
