"""Writing a report's files: text a person reads whatever bytes a file name held, and whole files or none.

A file name on Linux is bytes; Python hands an undecodable byte to rig as a lone surrogate (PEP 383), which neither
UTF-8 nor matplotlib's font engine accepts. `shown` writes such a byte as \\xNN, as `ls -b` does. A file is written
beside its final path and renamed over it (`aside`), so a kill or a full disk leaves the old file or none, never a
part of one.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any, Iterator


def shown(text: str) -> str:
    """`text` with each undecodable byte of a file name (a lone surrogate) written as \\xNN."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


@contextlib.contextmanager
def aside(path: str | Path) -> Iterator[Path]:
    """A path beside `path` to write to; renamed over `path` when the block ends, removed if it raises."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.writing")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def save_figure(fig: Any, path: str | Path, **savefig: Any) -> Path:
    """A matplotlib figure saved to `path` (its format from the suffix), its texts `shown`, whole or not at all."""
    import matplotlib.text

    for t in fig.findobj(matplotlib.text.Text):
        text = t.get_text()
        if text and text != shown(text):
            t.set_text(shown(text))
    path = Path(path)
    with aside(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", **savefig)
    return path


def write_text(path: str | Path, text: str) -> Path:
    """`text` (UTF-8, file names `shown`) written to `path`, whole or not at all."""
    path = Path(path)
    with aside(path) as tmp:
        tmp.write_text(shown(text), encoding="utf-8")
    return path
