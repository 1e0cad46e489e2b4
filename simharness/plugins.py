"""Names -> predictors and planners: the one loader every command, env and worker calls.

A predictor is named by
- a built-in name (`const-vel`, `const-vel:N`, `traphic`, a baseline; `simharness.predictors`) or a run
  folder written by `simharness train`;
- `path/to/file.py:NAME`: the file is imported under a private module name (never as `__main__`, so a
  file without an `if __name__ == "__main__":` guard is safe in worker processes), its folder importable;
- `package.module:NAME`: an importable module (installed, on PYTHONPATH, or in the current folder);
- a name an installed package registers in the entry-point group `simharness.predictors`.

NAME is a `Predictor` instance, a `Predictor` class, or a zero-argument factory returning one. Planners
are named the same way (`pdm`, `sampling`, `ppo`, an SB3 policy `.zip`, `file.py:NAME`, `module:NAME`,
entry points in `simharness.planners`); NAME is then a `Planner`, a class, or a zero-argument factory.

Workers are sent the name (a string), never the object, and load it here themselves. A plug-in that
fails to import or construct, or is not a predictor / planner, is one `UserError` line naming it.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import os
import re
import sys
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Any

from simharness.errors import UserError
from simharness.scene import Predictor

if TYPE_CHECKING:
    from simharness.planners import Planner
    from simharness.scenario import ScenarioSpec
    from simharness.sim.base import RoadGeometry

PREDICTOR_GROUP = "simharness.predictors"
PLANNER_GROUP = "simharness.planners"
_MODULE_SPEC = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")
_FILE_SPEC = re.compile(r"^(?P<path>.+\.py):(?P<attr>[A-Za-z_]\w*(\.[A-Za-z_]\w*)*)$")


# ---------------------------------------------------------------------- plug-in objects
def is_plugin(spec: str) -> bool:
    """Whether `spec` has the form `file.py:NAME` or `module:NAME` (not whether it loads)."""
    return bool(_FILE_SPEC.match(spec) or _MODULE_SPEC.match(spec))


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0]}" if text else type(e).__name__


def _import_file(path: Path, kind: str, spec: str) -> Any:
    """The module of a plug-in file, imported once per process under a private name (never `__main__`)."""
    if not path.is_file():
        raise UserError(f"{kind} plug-in {spec!r}: no such file {path}")
    resolved = path.resolve()
    digest = hashlib.sha1(str(resolved).encode()).hexdigest()[:12]
    stem = re.sub(r"\W", "_", resolved.stem)
    name = f"_simharness_plugin_{stem}_{digest}"
    if name in sys.modules:
        return sys.modules[name]
    folder = str(resolved.parent)
    if folder not in sys.path:  # its sibling modules import as they would when the file is run
        sys.path.append(folder)
    module_spec = importlib.util.spec_from_file_location(name, resolved)
    if module_spec is None or module_spec.loader is None:
        raise UserError(f"{kind} plug-in {spec!r}: {path} cannot be imported as a Python module")
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[name] = module  # before running it: dataclasses and pickling look their module up here
    try:
        module_spec.loader.exec_module(module)
    except (Exception, SystemExit) as e:
        del sys.modules[name]
        raise UserError(f"{kind} plug-in {spec!r}: importing {path} failed: {_one_line(e)}") from None
    return module


def _import_module(module: str, kind: str, spec: str) -> Any:
    if "" not in sys.path and os.getcwd() not in sys.path:  # the console script does not see the current folder
        sys.path.append(os.getcwd())
    try:
        return importlib.import_module(module)
    except (Exception, SystemExit) as e:
        raise UserError(f"{kind} plug-in {spec!r}: importing module {module} failed: {_one_line(e)}") from None


def _attribute(module: Any, attr: str, kind: str, spec: str) -> Any:
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise UserError(f"{kind} plug-in {spec!r}: {getattr(module, '__file__', None) or module.__name__} "
                            f"has no attribute {attr!r}")
        obj = getattr(obj, part)
    return obj


def _entry_point(group: str, name: str) -> Any | None:
    """The installed entry point `name` of `group`, or None."""
    for ep in entry_points(group=group):
        if ep.name == name:
            return ep
    return None


def entry_point_names(group: str) -> list[str]:
    """Names installed packages register in an entry-point group, sorted."""
    return sorted({ep.name for ep in entry_points(group=group)})


def _plugin_object(spec: str, group: str, kind: str) -> Any | None:
    """The object a plug-in spec names (file.py:NAME, module:NAME, an entry point), or None if `spec` is none."""
    if m := _FILE_SPEC.match(spec):
        return _attribute(_import_file(Path(m["path"]), kind, spec), m["attr"], kind, spec)
    if _MODULE_SPEC.match(spec):
        module, attr = spec.split(":")
        return _attribute(_import_module(module, kind, spec), attr, kind, spec)
    if (ep := _entry_point(group, spec)) is not None:
        try:
            return ep.load()
        except (Exception, SystemExit) as e:
            raise UserError(f"{kind} plug-in {spec!r} (entry point {ep.value} in {group}): import failed: "
                            f"{_one_line(e)}") from None
    return None


def _construct(obj: Any, protocol: type, method: str, kind: str, spec: str) -> Any:
    """An instance of `protocol` from an instance, a class (called with no arguments) or a zero-argument factory."""
    made = obj
    if isinstance(obj, type) or (not isinstance(obj, protocol) and callable(obj)):
        try:
            made = obj()
        except (Exception, SystemExit) as e:
            raise UserError(f"{kind} plug-in {spec!r}: constructing it with no arguments failed: "
                            f"{_one_line(e)}") from None
    if isinstance(made, type) or not isinstance(made, protocol):
        raise UserError(f"{kind} plug-in {spec!r}: got {type(made).__name__}, expected a {protocol.__name__} (an "
                        f"object with .{method}()), a {protocol.__name__} class or a zero-argument factory "
                        "returning one")
    return made


# ---------------------------------------------------------------------- predictors
def predictor_names() -> list[str]:
    """Every predictor name accepted besides run folders and plug-in specs: built-ins, then entry points."""
    from simharness.predictors import available

    builtin = available()
    return [*builtin, *(n for n in entry_point_names(PREDICTOR_GROUP) if n not in builtin)]


def load_predictor(name: str | Path, references: Sequence[str] = ()) -> Predictor:
    """The predictor `name` names: built-in, run folder, file.py:NAME, module:NAME or entry point.

    references: names the caller handles itself (the closed loop's oracle, static, none), listed in the
    error for an unknown name. Raises UserError (one line) for an unknown name or a failing plug-in.
    """
    from simharness.predictors import builtin_predictor

    key = str(name)
    if (predictor := builtin_predictor(key)) is not None:
        return predictor
    obj = _plugin_object(key, PREDICTOR_GROUP, "predictor")
    if obj is not None:
        return _construct(obj, Predictor, "predict", "predictor", key)
    accepted = ", ".join([*predictor_names(), *references])
    raise UserError(f"unknown predictor {key!r}; expected one of {accepted}, const-vel:N, a run folder written by "
                    f"`simharness train`, FILE.py:NAME or MODULE:NAME (docs/predictors.md)")


def check_predictor(name: str | Path, references: Sequence[str] = ()) -> None:
    """Load `name` here once, so that a bad name fails in the parent before any worker starts (UserError)."""
    if str(name) not in references:
        load_predictor(name, references)


# ---------------------------------------------------------------------- planners
def _pdm(spec: ScenarioSpec, road: RoadGeometry | None) -> Planner:
    from simharness.pdm_planner import PDMPlanner
    from simharness.planners import EgoLimits

    return PDMPlanner(EgoLimits(max_speed=spec.road.speed_limit), road=road)


def _sampling(spec: ScenarioSpec, road: RoadGeometry | None) -> Planner:
    from simharness.planners import EgoLimits, SamplingPlanner

    return SamplingPlanner(EgoLimits(max_speed=spec.road.speed_limit), road=road)


def _ppo(spec: ScenarioSpec, road: RoadGeometry | None) -> Planner:
    from simharness.policy_planner import load_policy_planner

    return load_policy_planner()


# name -> factory(scenario, road): the planners that ship with the package
PLANNERS: dict[str, Callable[[ScenarioSpec, RoadGeometry | None], Planner]] = {
    "pdm": _pdm,  # the default: PDM-Closed-style planner on the forecasts (simharness.pdm_planner)
    "sampling": _sampling,  # prediction-aware sampling planner (simharness.planners)
    "ppo": _ppo,  # the shipped PPO policy trained on simharness/HighwayDense-v0 (ignores forecasts)
}


def planner_names() -> list[str]:
    """Every planner name accepted besides .zip policies and plug-in specs: built-ins, then entry points."""
    return [*PLANNERS, *(n for n in entry_point_names(PLANNER_GROUP) if n not in PLANNERS)]


def load_planner(name: str | Path, spec: ScenarioSpec, road: RoadGeometry | None = None) -> Planner:
    """The planner `name` names, for scenario `spec`: built-in, SB3 policy .zip, file.py:NAME, module:NAME
    or entry point. Plug-ins are built with no arguments; the loop hands them the road through `set_road`
    when they have one. Raises UserError (one line) for an unknown name or a failing plug-in."""
    from simharness.planners import Planner

    key = str(name)
    if key in PLANNERS:
        return PLANNERS[key](spec, road)
    if key.endswith(".zip"):
        from simharness.policy_planner import load_policy_planner

        return load_policy_planner(key)
    obj = _plugin_object(key, PLANNER_GROUP, "planner")
    if obj is not None:
        return _construct(obj, Planner, "plan", "planner", key)
    raise UserError(f"unknown planner {key!r}; expected one of {', '.join(planner_names())}, a stable-baselines3 "
                    "policy .zip, FILE.py:NAME or MODULE:NAME (docs/predictors.md)")


def check_planner(name: str | Path, spec: ScenarioSpec) -> None:
    """Load `name` here once, so that a bad name fails in the parent before any worker starts (UserError)."""
    load_planner(name, spec)


def label(name: str | Path) -> str:
    """A short label for tables and folder names: `dir/const_accel.py:ConstAccel` -> `const_accel:ConstAccel`,
    a run folder -> its folder name, anything else unchanged."""
    key = str(name)
    if m := _FILE_SPEC.match(key):
        return f"{Path(m['path']).stem}:{m['attr']}"
    if not is_plugin(key) and ("/" in key or os.sep in key):
        return Path(key).name or key
    return key
