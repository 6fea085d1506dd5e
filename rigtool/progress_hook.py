"""The one callback long work reports through: `progress(task, done, total)`. Analysis, the
store and the dataset call it; the interface layer passes one that draws rich's progress
(rigtool/progress.py) on a terminal, so nothing below it imports rich."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sized
from typing import Protocol, TypeVar

T = TypeVar("T")


class ProgressHook(Protocol):
    """Called when `done` of `total` parts of `task` (a short phrase) are finished; first
    with done = 0 when the task starts."""

    def __call__(self, task: str, done: int, total: int) -> None: ...


def no_progress(task: str, done: int, total: int) -> None:
    """The hook of library use and tests: reports nothing."""
    return None


def counted(items: Iterable[T], task: str, progress: ProgressHook,
            total: int | None = None) -> Iterator[T]:
    """`items`, reporting each one finished to `progress` (done 0 before the first)."""
    n = total if total is not None else len(items) if isinstance(items, Sized) else 0
    progress(task, 0, n)
    for i, item in enumerate(items, 1):
        yield item
        progress(task, i, max(n, i))
