"""Experiments: plans (what happens) and the runner (how it happens to devices and files).

    from protocols import perpendicular, Runner
    plan = perpendicular(frames_per_stop=300, projector_on=True)
    Runner(camera, stage).run(plan, "run.h5")

Everything an acquisition needs lives here: the plans and their capture settings, the runner,
the streaming statistics (`stats`), the recording format (`recording`), experiment files and
the import of folders of frames. It imports only `drivers`.
"""

from .capture_settings import CaptureSettings
from .catalogue import PROTOCOLS
from .perpendicular import perpendicular
from .plan import Capture, Configure, Home, Move, Plan, Settle
from .runner import Runner, RunError, RunResult
from .tilted import tilted

__all__ = ["perpendicular", "tilted", "PROTOCOLS", "CaptureSettings", "Plan", "Runner", "RunError", "RunResult",
           "Capture", "Configure", "Home", "Move", "Settle"]
