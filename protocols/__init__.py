"""Experiments: plans (what happens) and the runner (how it happens to devices and files).

    from protocols import perpendicular, Runner
    plan = perpendicular(frames_per_stop=300, projector_on=True)
    Runner(camera, stage).run(plan, "run.h5")
"""

from .perpendicular import perpendicular
from .plan import Capture, Configure, Home, Move, Plan, Settle
from .runner import Runner, RunError, RunResult
from .tilted import tilted

PROTOCOLS = {"perpendicular": perpendicular, "tilted": tilted}

__all__ = ["perpendicular", "tilted", "PROTOCOLS", "Plan", "Runner", "RunError", "RunResult",
           "Capture", "Configure", "Home", "Move", "Settle"]
