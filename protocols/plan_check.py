"""A plan checked whole before a run homes the stage or records anything: the one set of rules the
runner (so `rig run` and Python scripts), and the TUI's experiment form apply.

    problems = plan_problems(plan, RigLimits(travel_m=(0.3, 3.5), stage_name="fake-stage",
                                             image_shape=(60, 106)), output=Path("run.h5"))

Each problem is one line that names the setting and the fix. What is checked:

- every step's values, with the checks the protocols make (`plan_values`), so a plan built by
  hand in Python is held to what a plan from a file is;
- every stop still to record within the stage's travel (a serial stage knows it once opened);
- the output: not a folder, in a folder that can be written (nothing is created to find out);
- the free disk against the recording's size: each stop's upper bound (`disk_space.stop_bytes`)
  counted twice (the stop files, then the one file `finish` assembles from them), plus the copy of
  what a resumed file already holds.

`value_problem` checks one parameter by the protocol's own rules (the form checks each field as it
is typed); `resume_problems` says what a resumed run may not change.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

from . import stop_journal as journal
from .capture_settings import WARM_UP_PARAMS
from .catalogue import PROTOCOLS, current_params
from .disk_space import FILE_OVERHEAD_BYTES, RESERVE_BYTES, free_bytes, size_text, stop_bytes
from .plan import Capture, Configure, Move, Plan, Settle
from .plan_values import distance_m, frames


class PlanError(ValueError):
    """The plan cannot finish on this rig; `problems` holds one line per problem."""

    def __init__(self, problems: list[str]):
        super().__init__("; ".join(problems))
        self.problems = list(problems)


@dataclass(frozen=True)
class RigLimits:
    """What the devices allow, where known: the stage's travel (nearest, farthest camera-to-wall distance
    in m) and the camera's image (rows, columns)."""

    travel_m: tuple[float, float] | None = None
    stage_name: str = "stage"
    image_shape: tuple[int, int] | None = None
    #: where the travel comes from, as one more fix for stops beyond it (`Stage.travel_note`)
    travel_note: str = ""
    #: what the opened stage knows will stop any plan (`Stage.setup_problems`)
    stage_problems: tuple[str, ...] = ()

    @classmethod
    def of(cls, stage: Any, image_shape: tuple[int, int] | None = None) -> "RigLimits":
        """What an opened stage (and camera image) allow."""
        return cls(stage.limits_m, stage.name, image_shape, stage.travel_note(), tuple(stage.setup_problems()))


@dataclass(frozen=True)
class StopRecipe:
    """How one stop is recorded: where, after how much settling, with which settings and capture."""

    position_m: float | None
    settle_s: float
    settings: Any
    capture: Capture


def stop_recipes(plan: Plan) -> dict[str, StopRecipe]:
    """Each capture's recipe by stop label, in plan order (moves and settling are those before it)."""
    out: dict[str, StopRecipe] = {}
    settings, move, settle = None, None, 0.0
    for step in plan.steps():
        if isinstance(step, Configure):
            settings = step.settings
        elif isinstance(step, Move):
            move = step.position_m
        elif isinstance(step, Settle):
            settle += step.seconds
        elif isinstance(step, Capture):
            out[step.stop] = StopRecipe(move, settle, settings, step)
            move, settle = None, 0.0
    return out


# -- the checks -------------------------------------------------------------------------------


def plan_problems(plan: Plan, limits: RigLimits = RigLimits(), *, output: str | Path | None = None,
                  resume: bool = False, recorded: Iterable[str] = ()) -> list[str]:
    """Every reason the plan cannot finish on this rig (none: it can). Stops in `recorded` are not recorded
    again, so they need neither travel nor disk."""
    recorded = set(recorded)
    recipes = {k: r for k, r in stop_recipes(plan).items() if k not in recorded}
    problems = [*limits.stage_problems, *step_problems(plan, recipes)]
    if limits.travel_m is not None:
        problems += travel_problems(plan, recipes, limits)
    if output is not None:
        out = output_problems(Path(output))
        problems += out
        if not out and limits.image_shape is not None:
            problems += disk_problems(recipes, limits.image_shape, Path(output), resume=resume)
    return problems


def check_plan(plan: Plan, limits: RigLimits = RigLimits(), **kw: Any) -> None:
    """Raise PlanError listing every problem `plan_problems` finds."""
    problems = plan_problems(plan, limits, **kw)
    if problems:
        raise PlanError(problems)


def step_problems(plan: Plan, recipes: dict[str, StopRecipe]) -> list[str]:
    """Frames and positions out of range, by the protocols' own checks."""
    out = []
    for label, r in recipes.items():
        try:
            frames(f"{plan.name}: stop {label!r}", "n_frames", r.capture.n_frames)
            if r.position_m is not None:
                distance_m(f"{plan.name}: stop {label!r}", "position_m", r.position_m)
        except ValueError as e:
            out.append(str(e))
        name = len(journal.stop_file(Path("r.h5"), label).name.encode())
        if name > journal.MAX_NAME_BYTES:
            out.append(f"{plan.name}: stop {label[:40]!r}... has a name of {len(label)} characters, too long for the file "
                       f"its data are kept in ({name} bytes; at most {journal.MAX_NAME_BYTES}); give it a shorter name "
                       "(for an import, rename its folder)")
    return out


def travel_problems(plan: Plan, recipes: dict[str, StopRecipe], limits: RigLimits) -> list[str]:
    """One line for all the stops beyond the stage's travel."""
    assert limits.travel_m is not None
    lo, hi = limits.travel_m
    outside = [r.position_m for r in recipes.values()
               if r.position_m is not None and not lo <= r.position_m <= hi]
    if not outside:
        return []
    setting = plan.stops_param or "the plan's stops"
    where = ", ".join(f"{z:.3f} m" for z in outside[:6]) + (", ..." if len(outside) > 6 else "")
    verb = "is" if len(outside) == 1 else "are"
    return [f"{setting}: {where} {verb} outside the travel of {limits.stage_name}, {lo:.3f}-{hi:.3f} m; "
            f"give stops within {lo:.3f}-{hi:.3f} m, or move the rail's zero (the stage's offset_m)"
            + (f", or {limits.travel_note}" if limits.travel_note else "")]


def output_problems(path: Path) -> list[str]:
    """Whether a recording can be written at `path`, without writing anything."""
    if path.is_dir():
        return [f"output {path} is a folder; give a file name in it, e.g. {path / 'run.h5'}"]
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        return [f"output {path}: {folder} is a file, not a folder; choose another output file"]
    if not os.access(folder, os.W_OK | os.X_OK):
        return [f"output {path}: the folder {folder} cannot be written (read-only or no permission); "
                "choose another output file or folder"]
    return []


def recording_bytes(recipes: dict[str, StopRecipe], image_shape: tuple[int, int]) -> int:
    """Upper bound on the stop files of these stops, bytes (as the runner checks before each stop)."""
    return sum(stop_bytes(image_shape, r.capture.n_frames, keep_raw=r.capture.keep_raw, ir=r.capture.ir,
                          ambient=r.capture.ambient_frames > 0) for r in recipes.values())


def bytes_on_disk(path: Path) -> int:
    """What a recording already takes: its file and its completed stop files."""
    files = [path, *journal.completed_stop_files(path).values()]
    return sum(p.stat().st_size for p in files if p.is_file())


def disk_need_bytes(recipes: dict[str, StopRecipe], image_shape: tuple[int, int], path: Path, *,
                    resume: bool = False) -> int:
    """Free space the whole run needs at its peak: the new stop files, then the assembled copy of
    everything (the file as it is now, and the new stops), and the runner's reserve."""
    new = recording_bytes(recipes, image_shape)
    existing = bytes_on_disk(path) if resume else 0
    return 2 * new + existing + FILE_OVERHEAD_BYTES + RESERVE_BYTES


def disk_problems(recipes: dict[str, StopRecipe], image_shape: tuple[int, int], path: Path, *,
                  resume: bool = False) -> list[str]:
    if not recipes:
        return []
    need = disk_need_bytes(recipes, image_shape, path, resume=resume)
    free = free_bytes(path.parent)
    if need <= free:
        return []
    n = len(recipes)
    return [f"disk: the recording needs up to {size_text(need)} ({n} stop{'s' * (n != 1)} of "
            f"{image_shape[1]}x{image_shape[0]} px, and a copy while they are assembled into one file) and "
            f"{size_text(free)} are free in {_folder(path)}; free about {size_text(need - free)}, record fewer "
            "stops or frames, or write the output to another disk"]


def _folder(path: Path) -> Path:
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder


def value_problem(protocol: str, name: str, value: Any) -> str | None:
    """The protocol's own objection to one parameter's value (the others at their defaults), or None."""
    try:
        PROTOCOLS[protocol](**{name: value})
    except (TypeError, ValueError) as e:
        return str(e)
    return None


# -- resuming ---------------------------------------------------------------------------------


def _plain(x: Any) -> Any:
    return json.loads(json.dumps(x, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def resume_problems(protocol: str, old_params: dict[str, Any], plan: Plan, recorded: Iterable[str]) -> list[str]:
    """Why `plan` may not carry on a recording made by `protocol` with `old_params` (none: it may).

    The stops not yet recorded may change: added, moved or dropped (the plan's `stops_param`). Every
    recorded stop must stay in the plan and be recorded the same way (position, frames, settling,
    camera settings), and every other parameter must be as in the file, but the warm-up's (WARM_UP_PARAMS: they
    change no stop's recording). With no stop recorded, nothing is kept, so anything may change.
    """
    recorded = set(recorded)
    old_params = current_params(old_params)  # a recording made before a parameter was renamed (frames -> frames_per_stop)
    if protocol != plan.name:
        return [f"protocol {protocol!r} in the file, {plan.name!r} now"]
    if not recorded:
        return []
    old, new = _plain(old_params), _plain(plan.params)
    k = plan.stops_param
    problems = [f"plan {name} {old.get(name)!r} in the file, {new.get(name)!r} now"
                for name in dict.fromkeys([*old, *new])
                if name != k and name not in WARM_UP_PARAMS and old.get(name) != new.get(name)]
    if problems or not k or old.get(k) == new.get(k):
        return problems
    try:
        before = stop_recipes(PROTOCOLS[protocol](**old_params))
    except (KeyError, TypeError, ValueError):  # the file's plan cannot be rebuilt, so its stops cannot be compared
        return [f"plan {k} {old.get(k)!r} in the file, {new.get(k)!r} now"]
    now = stop_recipes(plan)
    for label in [s for s in before if s in recorded] + sorted(recorded - set(before)):
        if label not in now:
            problems.append(f"stop {label} is recorded but {k} now leaves it out: {k} {old.get(k)!r} in the file, "
                            f"{new.get(k)!r} now; keep every recorded stop in {k}")
        elif label in before and before[label] != now[label]:
            problems.append(f"stop {label} is recorded but would be recorded differently now: {k} {old.get(k)!r} "
                            f"in the file, {new.get(k)!r} now")
    return problems


def plan_change(old_params: dict[str, Any], new_params: dict[str, Any]) -> str:
    """The parameters a resumed run changes, in words ("" when none)."""
    old, new = _plain(current_params(old_params)), _plain(new_params)
    return "; ".join(f"{k} {old.get(k)!r} in the file, {new.get(k)!r} now"
                     for k in dict.fromkeys([*old, *new]) if old.get(k) != new.get(k))
