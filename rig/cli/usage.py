"""The command line's own error: bad input, with what to type instead."""


class UsageError(ValueError):
    """Bad command-line input; the message says what to type instead."""
