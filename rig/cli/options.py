"""Options every command takes: `-v` (more detail, repeatable) and `-q` (no progress, no chatter on stderr);
and the check of output options (`--plot FILE`, `--out DIR`, ...) before the work they come at the end of.

-v and -q may be given before the command (`rig -q fit run.h5`) or after it (`rig fit run.h5 -q`).
Results (stdout) are the same at every verbosity; only what goes to stderr changes.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .usage import UsageError

#: the exit status of a command that worked but fitted a lambda the data do not determine (rig.models.data.determinacy)
EXIT_UNDETERMINED = 3

def at_least(low: int, what: str):
    """An argparse type: a whole number of at least `low`, else a one-line error naming `what` it counts and the fix
    (`--jobs 0` -> "0 is not a count of processes; give 1 or more")."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number; give {what} as {low} or more") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"{value} is not a count of {what}; give {low} or more")
        return value

    parse.__name__ = "count"  # argparse names the type in its messages
    return parse


def refuse_suffix(path: str | Path | None, option: str, suffixes: tuple[str, ...], what: str) -> None:
    """A one-line UsageError when `path`'s suffix is another kind of file's (`-o run.png` would hold HDF5): an unknown
    suffix is the user's choice, a known one of something else is a slip. `what` names the file, e.g. "a recording"."""
    if path is None:
        return
    suffix = Path(path).suffix.lower()
    if suffix and suffix not in suffixes and suffix in OTHER_KINDS:
        raise UsageError(f"{option} {path}: a {suffix} name for {what}, which is {suffixes[0]}; name it "
                         f"{Path(path).with_suffix(suffixes[0]).name}")


#: suffixes of files that are not what rig writes to them: images, tables, text, archives, other data
OTHER_KINDS = (".png", ".jpg", ".jpeg", ".svg", ".pdf", ".tif", ".tiff", ".csv", ".txt", ".md", ".html", ".json",
               ".toml", ".npy", ".npz", ".bag", ".db3", ".mcap", ".zip", ".gz", ".py", ".h5", ".hdf5")


QUIET = -1
NORMAL = 0
VERBOSE = 1


def add_verbosity(parser: argparse.ArgumentParser, *, top: bool) -> None:
    """-v/-q on `parser`. On a sub-command they default to nothing, so a flag given before the command stays."""
    defaults = {} if top else {"default": argparse.SUPPRESS}
    have = parser._option_string_actions  # a command with a -v of its own (stage-sim) keeps it
    if "-v" not in have:
        parser.add_argument("-v", "--verbose", action="count", help="more detail in the progress on stderr (repeatable)",
                            **({"default": 0} if top else defaults))
    if "-q" not in have:
        parser.add_argument("-q", "--quiet", action="store_true", help="no progress or other chatter on stderr",
                            **({"default": False} if top else defaults))


def verbosity(args: argparse.Namespace) -> int:
    """QUIET (-q), NORMAL, or VERBOSE and above (-v, -vv)."""
    if getattr(args, "quiet", False):
        return QUIET
    return int(getattr(args, "verbose", 0) or 0)


def refuse_unwritable(path: str | Path | None, option: str, *, folder: bool = False) -> None:
    """A one-line UsageError now, before any work, if the output `option` names cannot be written."""
    from ..reports.writable import output_problem

    problem = None if path is None else output_problem(path, folder=folder)
    if problem:
        what = "a folder" if folder else "a file"
        raise UsageError(f"cannot write {option} {path}: {problem}; give {option} {what} you can write to")

