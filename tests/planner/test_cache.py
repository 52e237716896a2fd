"""The bounded cache behind the planner's reuse of solvers, leaf templates and QPs."""

from __future__ import annotations

import pytest

from planner.cache import BoundedCache


def test_builds_once_per_key_and_forgets_the_oldest_when_full() -> None:
    built: list[str] = []
    cache: BoundedCache[str] = BoundedCache(2)

    def get(key: str) -> tuple[str, bool]:
        return cache.get_or_build(key, lambda: built.append(key) or key.upper())

    assert get("a") == ("A", False) and get("a") == ("A", True)
    assert get("b") == ("B", False) and len(cache) == 2
    assert get("c") == ("C", False)  # full: "a", the oldest, is forgotten
    assert "a" not in cache and "b" in cache and "c" in cache and len(cache) == 2
    assert get("a") == ("A", False)  # built again
    assert built == ["a", "b", "c", "a"]
    cache.clear()
    assert len(cache) == 0


def test_a_failed_build_keeps_nothing() -> None:
    cache: BoundedCache[int] = BoundedCache(1)

    def fail() -> int:
        raise RuntimeError("no")

    with pytest.raises(RuntimeError):
        cache.get_or_build("k", fail)
    assert "k" not in cache
    with pytest.raises(ValueError, match="size"):
        BoundedCache(0)
