"""A bounded per-process cache: built CasADi solvers, leaf templates and QP solvers are reused
across re-plans, and a ground station re-planning with other boxes or fleets must not grow
without bound, so the oldest entry is forgotten first."""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

V = TypeVar("V")


class BoundedCache(Generic[V]):
    """At most ``size`` values by key; adding to a full cache forgets the oldest first."""

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f"cache size must be >= 1, got {size!r}")
        self.size = size
        self._items: dict[Hashable, V] = {}

    def get_or_build(self, key: Hashable, build: Callable[[], V]) -> tuple[V, bool]:
        """The value under ``key`` and whether it was cached (else ``build()`` it and keep it)."""
        if key in self._items:
            return self._items[key], True
        value = build()
        while len(self._items) >= self.size:
            self._items.pop(next(iter(self._items)))
        self._items[key] = value
        return value, False

    def clear(self) -> None:
        self._items.clear()

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._items
