"""rig: drive a depth-camera calibration rig, fit sigma_Z = k * Z^lambda and diagnose what the model misses.

`rig.__version__` is the installed package's version (`importlib.metadata`); a source tree that
was never installed reads it from its `pyproject.toml`, and says "unknown" if neither exists.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

__all__ = ["__version__"]


@lru_cache(maxsize=1)
def package_version() -> str:
    """The version of this rig: the installed distribution's, else the source tree's pyproject.toml, else "unknown"."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("rig")
    except PackageNotFoundError:
        pass
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    try:
        import tomllib

        return str(tomllib.loads(pyproject.read_text())["project"]["version"]) + "+source"
    except (OSError, KeyError, ValueError):
        return "unknown"


def __getattr__(name: str) -> str:
    # read lazily: every `import rig.x` runs this module, and most never need the version
    if name == "__version__":
        return package_version()
    raise AttributeError(f"module 'rig' has no attribute {name!r}")
