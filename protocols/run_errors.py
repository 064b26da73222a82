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


def saved_words(saved: int, n: int, path: object) -> str:
    """What a stopped run kept, in words that are true: "1 stop is saved", "3 of 5 stops are saved ... to record the
    rest", and with every stop saved (only the final file missing) that --resume assembles it."""
    if saved >= n:
        every = f"all {n} stops are" if n != 1 else "the stop is"
        return f"{every} saved (in {path}.stops/); re-run the same command with --resume to assemble {path}"
    return (f"{saved} of {n} stop{'s are' if n != 1 else ' is'} saved in {path}; re-run the same command with --resume "
            "to record the rest")
