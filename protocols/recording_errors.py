"""The one error a recording's readers and writers raise."""


class RecordingError(ValueError):
    """A file is not a valid recording, or cannot be written; the message names the file, what is wrong and the fix."""


class AssemblyError(RecordingError):
    """Every stop is saved, but the final file could not be assembled (a full disk): the message says how to
    finish it (--resume), and nothing is left to record."""
