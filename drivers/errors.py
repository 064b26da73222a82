"""Errors raised by devices: one line that names the problem and what to do about it."""


class DeviceError(RuntimeError):
    """A device failed or refused; the message is one line: the problem, then the fix."""


class CameraError(DeviceError):
    """The depth camera failed, refused a setting, or reported something other than asked."""


class StageError(DeviceError):
    """The linear stage failed, refused a move, or is not where it was sent."""


class FolderImportError(ValueError):
    """A folder of frames cannot be imported; the one-line message names the file and the problem."""
