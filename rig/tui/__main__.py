"""`python -m rig.tui`: the same as `rig tui`."""

import sys

from . import tui_main

sys.exit(tui_main(sys.argv[1:]))
