"""`rig tui`: the lab operator's terminal UI (Textual). See docs/tui.md.

Importing this package does not import Textual; `tui_main` does, when it is called.
"""

from __future__ import annotations


def tui_main(argv: list[str] | None = None) -> int:
    """Run the terminal UI: `rig tui [--camera S] [--stage S] [--experiment FILE.toml] [RECORDING.h5]`."""
    import argparse

    from .launch import add_arguments, run

    p = argparse.ArgumentParser(prog="rig tui", description="The lab operator's terminal UI: devices, experiment, run, results.")
    add_arguments(p)
    return run(p.parse_args(argv))


__all__ = ["tui_main"]
