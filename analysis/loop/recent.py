"""A small memory of an expensive call's last results, for the loop's repeated asks.

A step asks for the same simulations more than once: each fit's runs are reported
several times (`runs`), and every candidate that reaches the fold-by-fold check
needs the same refits of the model without it (`validation`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


class Recent:
    """The last few results of an expensive call, keyed by the identity of its inputs.

    Fits and runs are immutable objects passed around by reference, so identity is
    the right key: a step's candidates ask for the same fold refits, and each fit's
    runs are reported several times. Held references keep the ids from being reused.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self.items: list[tuple[tuple[object, ...], object]] = []

    def get(self, key: tuple[object, ...], compute: Callable[[], T]) -> T:
        for k, value in self.items:
            if len(k) == len(key) and all(a is b or (isinstance(a, tuple) and a == b)
                                          for a, b in zip(k, key)):
                return value
        value = compute()
        self.items.append((key, value))
        del self.items[:-self.size]
        return value
