"""Folders of captured depth frames (16-bit PNG or .npy), read as a camera: the `rig import` source.

`manifest` reads rig-import.toml, `frame_files` the PNG/.npy headers and frames, `stops` finds
and checks each stop's sub-folder, `camera` replays them to the runner. The import itself
(plan, runner, provenance) is `protocols.folder_import`. See docs/import.md.
"""

from ..errors import FolderImportError
from .camera import FolderCamera
from .manifest import MANIFEST_NAME, ImportSettings, load_settings
from .stops import StopSource, check_stops, find_stops

__all__ = ["FolderImportError", "FolderCamera", "MANIFEST_NAME", "ImportSettings", "load_settings", "StopSource",
           "check_stops", "find_stops"]
