"""`rig check`: recordings judged against a specification (docs/check.md).

`spec` reads the spec (TOML) into lines; `figures` measures a recording with rig's own estimators (the paper's fit,
each stop's fill and accuracy); `verdicts` judges each line with the measurement's own error; `report` writes the
verdicts as text and as `rig.check/1` JSON.
"""

from .figures import RecordingFigures, measure
from .report import document, render
from .spec import Spec, SpecError, read_spec
from .verdicts import RecordingVerdict, evaluate, exit_status

__all__ = ["RecordingFigures", "RecordingVerdict", "Spec", "SpecError", "document", "evaluate", "exit_status",
           "measure", "read_spec", "render"]
