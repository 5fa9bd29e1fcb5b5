"""Progress bars for long work (rich), shared by the library and the flows: `progress` around a loop, `StepBar` for
work that reports its steps by callback (a training loop's epochs)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import TypeVar

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

T = TypeVar("T")


def _bar() -> Progress:
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    return Progress(*columns, transient=False)


def progress(items: Iterable[T], total: int | None = None, description: str = "working") -> Iterator[T]:
    """Yield from `items` while drawing a progress bar on stderr (a final line only when not a terminal; none for
    no items, `total` 0)."""
    if total == 0:
        yield from items
        return
    with _bar() as bar:
        task = bar.add_task(description, total=total)
        for item in items:
            yield item
            bar.advance(task)


class StepBar:
    """A progress bar of `total` steps moved on by `update` (steps done so far, and what the bar says); drawn from
    the first update (a resumed run starts past zero) and closed at the last step."""

    def __init__(self, total: int, description: str) -> None:
        self.total, self.description = total, description
        self._bar: Progress | None = None
        self._task = None

    def update(self, done: int, note: str = "") -> None:
        if self._bar is None:
            self._bar = _bar()
            self._bar.start()
            self._task = self._bar.add_task(self.description, total=self.total)
        described = f"{self.description} {note}".strip()
        self._bar.update(self._task, completed=min(done, self.total), description=described)
        if done >= self.total:
            self._bar.stop()
