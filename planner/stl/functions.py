"""Function predicates: a registry the scenario fills with ``inside``, ``outside``, ``dist``, ...

A :class:`Function` has a name, an arity and two implementations of the same mathematics:

``numpy_impl(args, signals) -> ndarray of shape (m,)``
``casadi_impl(args, signals) -> CasADi column of shape (m, 1)`` (SX or MX, as the signals)

``args`` is the tuple of identifier arguments as written (``("d1", "pole1")``): signal names or
names the function resolves itself (regions, obstacles). ``signals`` is a read-only mapping
``name -> rows`` in which **every array has the same number of rows m**, one row per sample
step the engine needs, in time order:

* numpy: scalar signals (m,), vector signals (m, d) (vehicle positions: d = 3, ENU metres);
* CasADi: scalar signals (m, 1), vector signals (m, d) SX/MX matrices.

For exact robustness ``m`` is the whole trace; for smooth robustness it is the contiguous block
of steps the formula reaches from t = 0 (rows ``lo..hi`` of the trace), so the CasADi graph holds
only what the optimiser needs. A function must therefore act **row-wise**: row ``i`` of its output
depends only on row ``i`` of its inputs. A missing name raises
:class:`~planner.stl.errors.UnknownSignalError` from the mapping itself.

Example (the planner's kind of function)::

    def dist_np(args, signals):
        return np.linalg.norm(signals[args[0]] - signals[args[1]], axis=1)

    def dist_ca(args, signals):
        diff = signals[args[0]] - signals[args[1]]
        return ca.sqrt(ca.sum2(diff**2) + 1e-12)

    registry = FunctionRegistry()
    registry.register("dist", 2, dist_np, dist_ca, signal_args=(0, 1))
    phi = parse("always[0,10] (dist(d1, d2) >= 0.5)", registry)

Used as an atom (``inside(d1, pole1)``) a function means ``f(...) >= 0``: its robustness is its
value (a signed margin, positive when satisfied).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.stl.ast import IDENTIFIER_RE, RESERVED
from planner.stl.errors import RegistryError, UnknownSignalError

#: numpy implementation: (args, signals) -> (m,) array.
NumpyImpl = Callable[[tuple[str, ...], Mapping[str, Any]], Any]
#: CasADi implementation: (args, signals) -> (m, 1) SX/MX column.
CasadiImpl = Callable[[tuple[str, ...], Mapping[str, Any]], Any]


@dataclass(frozen=True, slots=True)
class Function:
    """A named function usable in specifications.

    Attributes:
        name: identifier used in the text.
        arity: number of identifier arguments.
        numpy_impl: ``(args, signals) -> (m,)`` float array (see module docstring).
        casadi_impl: ``(args, signals) -> (m, 1)`` CasADi column.
        signal_args: positions of the arguments that name signals (e.g. ``(0,)`` for
            ``inside(d1, pole1)``); ``None`` when undeclared. Only used to report which signals
            a formula reads (:meth:`Formula.signal_names`).
    """

    name: str
    arity: int
    numpy_impl: NumpyImpl
    casadi_impl: CasadiImpl
    signal_args: tuple[int, ...] | None = None

    def signal_names(self, args: tuple[str, ...]) -> tuple[str, ...]:
        """The arguments of a call that name signals (empty when undeclared)."""
        if self.signal_args is None:
            return ()
        return tuple(args[i] for i in self.signal_args)


class FunctionRegistry:
    """Functions available to :func:`planner.stl.parse`, by name."""

    def __init__(self, functions: tuple[Function, ...] | list[Function] = ()) -> None:
        self._functions: dict[str, Function] = {}
        for function in functions:
            self.add(function)

    def register(
        self,
        name: str,
        arity: int,
        numpy_impl: NumpyImpl,
        casadi_impl: CasadiImpl,
        *,
        signal_args: tuple[int, ...] | None = None,
    ) -> Function:
        """Create and add a :class:`Function`; returns it.

        Raises:
            RegistryError: bad name, a name already registered, arity < 0, bad signal_args,
                or implementations that are not callable.
        """
        return self.add(Function(name, arity, numpy_impl, casadi_impl, signal_args))

    def add(self, function: Function) -> Function:
        """Add an existing :class:`Function` (same checks as :meth:`register`)."""
        name = function.name
        if not isinstance(name, str) or not IDENTIFIER_RE.match(name):
            raise RegistryError(f"function name {name!r} is not an identifier")
        if name in RESERVED:
            raise RegistryError(f"function name {name!r} is a reserved word")
        if name in self._functions:
            raise RegistryError(f"function {name!r} is already registered")
        if isinstance(function.arity, bool) or not isinstance(function.arity, int):
            raise RegistryError(f"function {name!r}: arity must be an int")
        if function.arity < 0:
            raise RegistryError(f"function {name!r}: arity must be >= 0")
        if not callable(function.numpy_impl) or not callable(function.casadi_impl):
            raise RegistryError(f"function {name!r}: implementations must be callable")
        if function.signal_args is not None and any(
            not 0 <= i < function.arity for i in function.signal_args
        ):
            raise RegistryError(f"function {name!r}: signal_args out of range")
        self._functions[name] = function
        return function

    def __getitem__(self, name: str) -> Function:
        return self._functions[name]

    def get(self, name: str) -> Function | None:
        """The function called ``name``, or None."""
        return self._functions.get(name)

    def __contains__(self, name: object) -> bool:
        return name in self._functions

    def __iter__(self) -> Iterator[str]:
        return iter(self._functions)

    def __len__(self) -> int:
        return len(self._functions)

    def __repr__(self) -> str:
        return f"FunctionRegistry({sorted(self._functions)})"


class RowView(Mapping[str, Any]):
    """Read-only view of signals restricted to rows ``lo..hi-1`` (sliced lazily, cached).

    Missing names raise :class:`UnknownSignalError` naming the signal.
    """

    def __init__(self, signals: Mapping[str, Any], lo: int, hi: int) -> None:
        self._signals = signals
        self._lo = lo
        self._hi = hi
        self._cache: dict[str, Any] = {}

    def __getitem__(self, name: str) -> Any:
        if name in self._cache:
            return self._cache[name]
        if name not in self._signals:
            raise UnknownSignalError(name, tuple(self._signals))
        value = self._signals[name]
        if isinstance(value, np.ndarray) and value.ndim == 1:
            rows = value[self._lo : self._hi]
        else:  # numpy (n, d) or any CasADi matrix
            rows = value[self._lo : self._hi, :]
        self._cache[name] = rows
        return rows

    def __iter__(self) -> Iterator[str]:
        return iter(self._signals)

    def __len__(self) -> int:
        return len(self._signals)

    def __contains__(self, name: object) -> bool:
        return name in self._signals
