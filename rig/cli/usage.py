"""The command line's own error: bad input, with what to type instead."""


class UsageError(ValueError):
    """Bad command-line input; the message says what to type instead."""


def say_done(line: str, done: str) -> None:
    """Print a command's last line, which says what it wrote (`done`: those files, in words). Where the standard output
    is on a full disk, the line is lost but the work is not: a UsageError says so, not "run the command again" (which
    would find the file there)."""
    import errno
    import sys

    try:
        print(line)
        sys.stdout.flush()
    except OSError as e:
        if e.errno != errno.ENOSPC:
            raise
        raise UsageError(f"disk full writing the standard output: {done} complete; only the line saying so is lost "
                         "(free some space, or send the output elsewhere)") from None
