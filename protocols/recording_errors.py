"""The one error a recording's readers and writers raise."""


class RecordingError(ValueError):
    """A file is not a valid recording, or cannot be written; the message names the file, what is wrong and the fix."""
