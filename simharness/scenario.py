"""Scenario files: TOML, one per scenario, loaded and validated into a `ScenarioSpec`.

Every section is a dataclass below; its fields (with defaults and a `doc`) are
the schema. A mistake raises `UserError` with one line naming the file, the
key and what was expected. Example (`scenarios/sumo_arterial_dense.toml`)::

    name = "sumo_arterial_dense"
    backend = "sumo"
    duration = 60.0
    [road]
    layout = "arterial"
    length = 500.0
    [demand]
    car = 1800
    motorcycle = 1500
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import sys
import types
import typing
from pathlib import Path
from typing import Any, Literal

from simharness.errors import UserError
from simharness.scene import LABELS, AgentType

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SCENARIO_DIR = Path(__file__).resolve().parent.parent / "scenarios"
MAX_SEED = 2**31 - 1  # simulators take 32-bit signed seeds
MAX_SCENARIO_BYTES = 1 << 20  # a scenario file is a few hundred bytes; more is not one


def _f(default: Any, doc: str, lo: float | None = None, hi: float | None = None, **kw: Any) -> Any:
    """A schema field: default, one-line doc, optional inclusive bounds."""
    factory = kw.pop("factory", None)
    meta = {"doc": doc, "lo": lo, "hi": hi}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@dataclasses.dataclass(frozen=True)
class RoadSpec:
    layout: Literal["arterial", "intersection"] = _f(
        "arterial", "arterial: a straight urban road; intersection: a four-way crossing")
    length: float = _f(500.0, "arterial length, or length of each intersection arm (m)", 50.0, 20000.0)
    width: float = _f(10.5, "carriageway width per direction (m)", 2.5, 40.0)
    lanes: int = _f(1, "marked lanes per direction; 1 makes one wide lane-less carriageway", 1, 8)
    bidirectional: bool = _f(False, "also build the opposite carriageway")
    sidewalk_width: float = _f(2.0, "sidewalk width each side (m); 0 for none", 0.0, 10.0)
    speed_limit: float = _f(13.9, "road speed limit (m/s)", 1.0, 45.0)


@dataclasses.dataclass(frozen=True)
class PedestrianSpec:
    crossing_rate: float = _f(0.0, "pedestrians crossing the carriageway, per hour", 0.0, 20000.0)
    walking_rate: float = _f(0.0, "pedestrians walking along the road edge among vehicles, per hour",
                             0.0, 20000.0)
    speed: float = _f(1.3, "mean walking speed (m/s)", 0.2, 3.0)


@dataclasses.dataclass(frozen=True)
class BehaviourSpec:
    spread: float = _f(0.5, "driver-behaviour spread: 0 all alike, 1 aggressive to conservative", 0.0, 1.0)
    speed_dev: float = _f(0.1, "std of each driver's speed factor around 1", 0.0, 0.5)


@dataclasses.dataclass(frozen=True)
class SublaneSpec:
    lateral_resolution: float = _f(0.35, "sub-lane width (m); 0 disables the sub-lane model", 0.0, 5.0)
    min_gap_lat: float = _f(0.3, "minimum lateral gap between agents (m)", 0.0, 3.0)
    lane_discipline: float = _f(0.0, "0 free lateral positions .. 1 keep to lane centres", 0.0, 1.0)


@dataclasses.dataclass(frozen=True)
class EgoSpec:
    enabled: bool = _f(False, "insert a harness-driven ego agent")
    type: str = _f("car", "AgentType of the ego")
    insert_at: float = _f(0.0, "seconds after warm-up at which the ego enters", 0.0, 3600.0)
    speed: float = _f(8.0, "initial ego speed (m/s)", 0.0, 45.0)
    reaction: Literal["reactive", "cut_in", "ignore"] = _f(
        "reactive", "background agents towards the ego: reactive, cut_in (no lateral yield), ignore")


EVENT_KINDS = ("brake", "cut_in", "step_out", "pull_out", "merge", "turn_across")
EVENT_ACTORS = {"brake": "truck", "cut_in": "motorcycle", "step_out": "pedestrian", "pull_out": "bus",
                "merge": "rickshaw", "turn_across": "car"}  # the actor each kind places when `actor` is left empty
SUMO_ONLY_EVENTS = ("turn_across",)


@dataclasses.dataclass(frozen=True)
class EventSpec:
    """One scripted event (`[[events]]`): an actor placed relative to the ego at `at`, then a manoeuvre.

    The actor is scripted from its placement on (it ignores everyone, the ego included), so what it
    does is a function of time alone and an oracle that branches the simulation sees it exactly.
    """

    kind: Literal["brake", "cut_in", "step_out", "pull_out", "merge", "turn_across"] = _f(
        "brake", "brake: a lead brakes hard; cut_in: an agent beside moves into the ego's band and brakes; "
        "step_out: a pedestrian steps out from in front of a stopped bus; pull_out: a stopped bus pulls out "
        "into the ego's band; merge: a slow agent joins from the edge into the ego's band; turn_across (sumo "
        "backend): an oncoming agent turns across the ego's path on a quarter circle")
    actor: str = _f("", "AgentType of the actor; empty: truck, motorcycle, pedestrian, bus, rickshaw, car by kind")
    at: float = _f(2.0, "seconds after warm-up at which the actor is placed (`lead` s earlier with a lead; "
                   "skipped if the ego is absent)",
                   0.0, 3600.0)
    ahead: float = _f(10.0, "m from the ego's front to the actor's rear at placement (negative: beside/behind)",
                      -50.0, 200.0)
    ahead_time: float = _f(0.0, "s of the ego's speed added to `ahead` (placement scales with the ego's speed)",
                           0.0, 20.0)
    side: float = _f(0.0, "m from the ego's centre line to the actor's at placement, + left (step_out, "
                     "pull_out: which kerb, by sign; 0 = right)", -20.0, 20.0)
    speed: float = _f(-1.0, "actor speed at placement (m/s); negative: the ego's speed", -1.0, 45.0)
    delay: float = _f(1.0, "s after `at` at which the manoeuvre starts", 0.0, 600.0)
    lead: float = _f(0.0, "s before `at` at which the actor enters, further ahead by what the ego (at its speed "
                     "then) closes on it in that time; it holds its speed and line until the manoeuvre, so it is "
                     "in view before it acts (0: it appears at `at`)", 0.0, 60.0)
    decel: float = _f(6.0, "m/s^2 of braking during the manoeuvre (brake, cut_in)", 0.0, 12.0)
    accel: float = _f(1.5, "m/s^2 of acceleration towards end_speed (pull_out, merge)", 0.0, 6.0)
    end_speed: float = _f(0.0, "m/s the actor brakes or accelerates to during the manoeuvre", 0.0, 45.0)
    lateral_speed: float = _f(1.5, "m/s of sideways motion towards the target (cut_in, step_out, pull_out, "
                              "merge)", 0.0, 6.0)
    target: float = _f(0.0, "m, + left: where the actor moves, from the ego's centre line at the manoeuvre "
                       "start (step_out: ignored, the pedestrian crosses the whole carriageway; turn_across: where "
                       "its quarter-circle turn ends)", -20.0, 20.0)


@dataclasses.dataclass(frozen=True)
class ReplaySpec:
    """How a recorded data set is replayed (`backend = "replay"`; see `simharness.sim.replay`)."""

    mode: Literal["log", "reactive"] = _f(
        "reactive", "log: everyone else replays the recording exactly; reactive: they follow their recorded paths "
        "with an IDM speed control that keeps a gap to the ego and to each other")
    edge_margin: float = _f(10.0, "m of recorded traffic the ego's episode keeps from the recording's edges, "
                            "behind its start and ahead of its end", 0.0, 1000.0)
    pixel_scale: float = _f(0.0, "metres per pixel for recordings in pixels (TRAF); 0: refuse them", 0.0, 100.0)


@dataclasses.dataclass(frozen=True)
class ScenarioSpec:
    """A whole scenario file. `path` and `source_text` are filled by the loader."""

    name: str = _f("", "scenario name (defaults to the file stem)")
    description: str = _f("", "one line for people")
    backend: Literal["sumo", "highway", "replay"] = _f("sumo", "simulator backend (replay: a recorded data set)")
    data: str = _f("", "data set folder replayed (backend = replay), relative to this file")
    seed: int = _f(0, "base seed; a job's seed is added to it", 0, 2**31 - 1)
    duration: float = _f(60.0, "recorded seconds per scene (after warm-up)", 0.1, 86400.0)
    warmup: float = _f(60.0, "unrecorded seconds to fill the road first", 0.0, 3600.0)
    step_length: float = _f(0.1, "simulator step (s)", 0.01, 1.0)
    record_hz: float = _f(5.0, "recorded frames per second", 0.1, 100.0)
    road: RoadSpec = _f(None, "road layout", factory=RoadSpec)
    demand: dict[str, float] = _f(None, "vehicles per hour by agent type (no pedestrian here)", 0.0, 50000.0,
                                  factory=dict)
    demand_scale: float = _f(1.0, "multiplies every demand and pedestrian rate", 0.0, 20.0)
    pedestrians: PedestrianSpec = _f(None, "pedestrian flows", factory=PedestrianSpec)
    behaviour: BehaviourSpec = _f(None, "driver behaviour", factory=BehaviourSpec)
    sublane: SublaneSpec = _f(None, "lateral (lane-less) movement", factory=SublaneSpec)
    ego: EgoSpec = _f(None, "the harness-driven ego agent", factory=EgoSpec)
    events: tuple[EventSpec, ...] = _f(None, "scripted events, [[events]] tables",
                                       factory=tuple)
    replay: ReplaySpec = _f(None, "replay of a recorded data set (backend = replay)", factory=ReplaySpec)
    path: str = dataclasses.field(default="", metadata={"internal": True})

    @property
    def dt(self) -> float:
        """Seconds per recorded frame."""
        return 1.0 / self.record_hz

    @property
    def steps_per_frame(self) -> int:
        return max(1, round(self.dt / self.step_length))

    @property
    def num_frames(self) -> int:
        return int(round(self.duration * self.record_hz))

    def sim_seed(self, seed: int) -> int:
        """The seed the simulator gets for job seed `seed`: the scenario's `seed` plus it; UserError (one line)
        if the sum leaves the simulators' 32-bit range."""
        total = int(self.seed) + int(seed)
        if not 0 <= total <= MAX_SEED:
            raise UserError(f"{self.path or self.name}: key 'seed' = {self.seed} plus job seed {seed} is {total}, "
                            f"outside the simulators' seed range 0..{MAX_SEED}; lower the scenario's seed or the "
                            "--seeds")
        return total

    def flows(self) -> dict[AgentType, float]:
        """Vehicles per hour by type, demand_scale applied."""
        return {AgentType.parse(k): v * self.demand_scale for k, v in self.demand.items()}

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d.pop("path")
        if not d["events"]:  # scenarios without events keep the config hash they had before events existed
            d.pop("events")
        for ev in d.get("events", []):  # and events without a lead the hash they had before leads existed
            if ev["lead"] == 0:
                ev.pop("lead")
        if self.backend != "replay":  # simulated scenarios keep their config hash too
            d.pop("data")
            d.pop("replay")
        return d

    def config_hash(self) -> str:
        """sha256 of the canonical JSON of the spec (path excluded), 16 hex digits."""
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def with_overrides(self, overrides: dict[str, Any]) -> ScenarioSpec:
        """Apply dotted-key overrides ("demand_scale", "road.width", "demand.car"), validated."""
        data = self.to_dict()
        for key, value in overrides.items():
            node = data
            *parents, leaf = key.split(".")
            for p in parents:
                if not isinstance(node.get(p), dict):
                    raise UserError(f"{self.path or self.name}: override {key!r}: unknown key {p!r}")
                node = node[p]
            node[leaf] = value
        return parse_scenario(data, self.path or self.name)


# ---------------------------------------------------------------------- loading
def resolve_scenario_path(name_or_path: str | Path) -> Path:
    """A path as given, or a shipped scenario by name ("sumo_arterial_dense")."""
    p = Path(name_or_path)
    if p.suffix != ".toml" and not p.exists():
        shipped = SCENARIO_DIR / f"{p}.toml"  # "sumo_arterial_dense", or "stress/step_out"
        if shipped.exists():
            return shipped
    return p


def load_scenario(name_or_path: str | Path) -> ScenarioSpec:
    """Read and validate a scenario file; UserError (one line) on any mistake."""
    path = resolve_scenario_path(name_or_path)
    if path.is_dir() and ((path / "_manifest.json").is_file() or (path / "manifest.json").is_file()):
        from simharness.sim.replay.scenario import replay_scenario

        return replay_scenario(path)
    if not path.is_file():
        shipped = ", ".join(sorted(p.relative_to(SCENARIO_DIR).with_suffix("").as_posix()
                                   for p in SCENARIO_DIR.glob("**/*.toml")))
        raise UserError(f"{path}: scenario file not found (shipped scenarios: {shipped})")
    size = path.stat().st_size
    if size > MAX_SCENARIO_BYTES:
        raise UserError(f"{path}: {size:,} bytes; a scenario file is at most {MAX_SCENARIO_BYTES:,}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise UserError(f"{path}: not valid TOML: {e}") from None
    except RecursionError:  # arrays or tables nested thousands deep: no scenario key nests more than 3
        raise UserError(f"{path}: not valid TOML for a scenario: nested too deeply") from None
    data.setdefault("name", path.stem)
    return parse_scenario(data, str(path))


def parse_scenario(data: dict[str, Any], where: str) -> ScenarioSpec:
    """Validate a dict (as read from TOML) into a ScenarioSpec."""
    spec = _build(ScenarioSpec, data, where, "")
    spec = dataclasses.replace(spec, path=where)
    try:
        AgentType.parse(spec.ego.type)
    except UserError:
        raise UserError(f"{where}: key 'ego.type': unknown agent type {spec.ego.type!r}; "
                        f"expected one of {', '.join(LABELS)}") from None
    if spec.step_length > spec.dt + 1e-9:
        raise UserError(f"{where}: key 'step_length': {spec.step_length} s is longer than one recorded "
                        f"frame (1/record_hz = {spec.dt} s)")
    if abs(spec.dt / spec.step_length - round(spec.dt / spec.step_length)) > 1e-6:
        raise UserError(f"{where}: key 'record_hz': 1/record_hz must be a whole number of step_length")
    for i, ev in enumerate(spec.events):
        try:
            AgentType.parse(ev.actor or EVENT_ACTORS[ev.kind])
        except UserError:
            raise UserError(f"{where}: key 'events[{i}].actor': unknown agent type {ev.actor!r}; "
                            f"expected one of {', '.join(LABELS)}") from None
        if ev.lead > ev.at + 1e-9:
            raise UserError(f"{where}: key 'events[{i}].lead': {ev.lead:g} s before at = {ev.at:g} s is before "
                            "the episode starts; expected lead <= at")
        if ev.kind in SUMO_ONLY_EVENTS and spec.backend != "sumo":
            raise UserError(f"{where}: key 'events[{i}].kind': {ev.kind!r} runs on the sumo backend only; "
                            f"expected one of {', '.join(k for k in EVENT_KINDS if k not in SUMO_ONLY_EVENTS)}")
    if spec.events and not spec.ego.enabled:
        raise UserError(f"{where}: key 'events': scripted events are placed relative to the ego; "
                        "expected ego.enabled = true")
    if spec.backend == "replay":
        if not spec.data:
            raise UserError(f"{where}: key 'data': backend = \"replay\" replays a data set folder; expected its path")
        if spec.events:
            raise UserError(f"{where}: key 'events': scripted events need a simulated backend, not replay")
        return spec
    people = (spec.pedestrians.crossing_rate + spec.pedestrians.walking_rate) * spec.demand_scale
    if not any(v > 0 for v in spec.flows().values()) and people == 0:
        raise UserError(f"{where}: key 'demand': no agents at all (every flow is 0 after demand_scale = "
                        f"{spec.demand_scale:g}); expected at least one positive flow")
    return spec


def _build(cls: type, table: Any, where: str, prefix: str) -> Any:
    if not isinstance(table, dict):
        raise UserError(f"{where}: key '{prefix.rstrip('.') or '(top)'}': expected a table, got "
                        f"{type(table).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if not f.metadata.get("internal")}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise UserError(f"{where}: key '{prefix}{unknown[0]}': unknown key; expected one of "
                        f"{', '.join(sorted(fields))}")
    values = {}
    for name, value in table.items():
        values[name] = _check(hints[name], value, fields[name].metadata, where, prefix + name)
    return cls(**values)


def _check(hint: Any, value: Any, meta: Any, where: str, key: str) -> Any:
    origin = typing.get_origin(hint)
    lo, hi = meta.get("lo"), meta.get("hi")

    def bad(expected: str) -> UserError:
        return UserError(f"{where}: key '{key}': expected {expected}, got {value!r}")

    if dataclasses.is_dataclass(hint):
        return _build(hint, value, where, key + ".")
    if origin is Literal:
        if value not in typing.get_args(hint):
            raise bad("one of " + ", ".join(repr(a) for a in typing.get_args(hint)))
        return value
    if origin is dict:
        if not isinstance(value, dict):
            raise bad("a table")
        out = {}
        for k, v in value.items():
            if k not in LABELS or k == "pedestrian":
                allowed = ", ".join(x for x in LABELS if x != "pedestrian")
                raise UserError(f"{where}: key '{key}.{k}': unknown agent type; expected one of {allowed}")
            out[k] = _check(float, v, meta, where, f"{key}.{k}")
        return out
    if origin is tuple:  # a list of tables ([[events]])
        item = typing.get_args(hint)[0]
        if not isinstance(value, (list, tuple)):
            raise bad("a list of tables ([[...]])")
        return tuple(_build(item, v, where, f"{key}[{i}].") for i, v in enumerate(value))
    if origin in (typing.Union, types.UnionType):  # pragma: no cover - unused so far
        raise TypeError(hint)
    if hint is bool:
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise bad("a string")
        return value
    if hint in (int, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (
                hint is int and not isinstance(value, int)):
            raise bad("an integer" if hint is int else "a number")
        if not math.isfinite(value):  # TOML reads nan and inf; no key means them, and comparisons let NaN by
            raise bad("a finite number")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise bad(f"a number in [{lo}, {hi}]")
        return hint(value)
    raise TypeError(f"unsupported schema type {hint}")  # pragma: no cover


def describe_schema() -> str:
    """Every key with its default and doc, for `simharness scenario --help` and the docs."""
    lines = []

    def walk(cls: type, prefix: str) -> None:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if f.metadata.get("internal"):
                continue
            if dataclasses.is_dataclass(hints[f.name]):
                lines.append(f"[{prefix}{f.name}]  {f.metadata['doc']}")
                walk(hints[f.name], prefix + f.name + ".")
                continue
            if typing.get_origin(hints[f.name]) is tuple:
                lines.append(f"[[{prefix}{f.name}]]  {f.metadata['doc']}")
                walk(typing.get_args(hints[f.name])[0], prefix + f.name + ".")
                continue
            default = f.default if f.default is not dataclasses.MISSING else "{}"
            lines.append(f"  {prefix}{f.name} = {default!r}  # {f.metadata['doc']}")

    walk(ScenarioSpec, "")
    return "\n".join(lines)


def scenario_command(args: Any) -> int:
    """`simharness scenario [FILE]`: check a file, or print the schema."""
    if not args.scenario:
        print(describe_schema())
        return 0
    spec = load_scenario(args.scenario)
    print(f"{spec.path}: ok ({spec.backend}, {spec.road.layout}, {spec.duration:g} s at {spec.record_hz:g} Hz, "
          f"config {spec.config_hash()})")
    return 0
