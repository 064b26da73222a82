"""What a stopped run raises, in a module of its own: the command line catches it around every command, and
importing the runner for that would load the streaming statistics and numba (0.5 s) into `rig --help`."""

from __future__ import annotations


class RunError(RuntimeError):
    """The run stopped; the message says why, what was saved and how to resume."""


class PlanRefused(RunError):
    """The plan cannot finish on this rig, found before homing or recording (`plan_check`); `problems` holds
    one line per problem."""

    def __init__(self, message: str, problems: list[str]):
        super().__init__(message)
        self.problems = problems
