"""Progress of long analysis work (fits, diagnoses), for a terminal line or the TUI.

Work that takes more than a moment takes an optional `progress` callable and calls it with a
`WorkProgress` as each step begins and when the work ends:

    def show(p: WorkProgress) -> None:
        print(f"{p.task} ({p.done}/{p.total})")

    diagnose(data, progress=show)

`total` is the number of steps expected in all; it is an estimate and may grow while the work
goes on (a diagnosis does not know in advance how many effects it will add): `more_may_come` says
when it still may, so a time left is a lower bound then. `done == total` with `finished` set means
the work is over.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class WorkProgress:
    """One progress report: what is being done now, and how far the whole work is."""

    task: str  # in words: "fitting active+noise_floor"
    done: int  # steps finished
    total: int  # steps expected in all (an estimate; may grow)
    finished: bool = False
    more_may_come: bool = False  # the work may still find steps it has not counted (total may grow)

    @property
    def fraction(self) -> float:
        return min(1.0, self.done / self.total) if self.total > 0 else 0.0


ProgressFn = Callable[[WorkProgress], None]


class ProgressCounter:
    """Counts steps of one piece of work and reports each to a `ProgressFn` (or to nobody)."""

    def __init__(self, progress: ProgressFn | None, total: int):
        self.progress = progress
        self.total = max(1, total)
        self.done = 0
        #: whether steps not counted yet may still come (the work sets it as it learns; see WorkProgress)
        self.more_may_come = False

    def step(self, task: str) -> None:
        """A step begins: report it with the steps finished so far, then count it as done."""
        if self.progress is not None:
            self.total = max(self.total, self.done + 1)
            self.progress(WorkProgress(task, self.done, self.total, more_may_come=self.more_may_come))
        self.done += 1

    def expect(self, more: int) -> None:
        """The work turned out to have `more` steps still to come than counted."""
        self.total = max(self.total, self.done + more)

    def finish(self, task: str = "done") -> None:
        if self.progress is not None:
            self.progress(WorkProgress(task, self.done, self.done, finished=True))
