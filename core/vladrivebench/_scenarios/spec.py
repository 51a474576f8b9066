"""Scenarios: the simulator-agnostic description of one driving situation, its loader and validator.

A scenario file (TOML or JSON) describes a road layout, the ego's start, the actors and road features, the
navigation command and which feature is *critical* (the one thing the CoT should be about). Positions are
given in route coordinates: ``s`` metres along the ego's route from the ego's start (the ego's centre starts
at ``s = 0``) and ``offset`` metres to the left of the ego lane's centre line. Every simulator turns these
into its own world; :mod:`vladrivebench.world._roads` builds the shared geometry.

Validation is strict: a wrong, missing or unknown field is one line naming the file, the field and what is
expected, so a typo never silently changes an experiment.
"""

from __future__ import annotations

import difflib
import fnmatch
import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from vladrivebench.errors import ConfigError, ScenarioError, UnknownNameError
from vladrivebench.records import LIGHT_COLOURS, NAV_COMMANDS

STEP_S = 0.1
LAYOUTS = ("straight", "t_junction", "four_way")
FAMILIES = ("pedestrian", "stopped_car", "traffic_light", "stop_sign", "baseline", "intervention")
JUNCTION_SIDES = ("through", "dead_end")
SIDES = ("left", "right")
SCENERIES = ("plain", "suburban", "urban")
MOTIONS = ("static", "along", "cross")
DIRECTIONS = ("same", "opposite")
ACTOR_SPEC_KINDS = ("pedestrian", "car", "animal")
FAMILY_CRITICAL_KIND = {
    "pedestrian": "pedestrian",
    "stopped_car": "car",
    "traffic_light": "traffic_light",
    "stop_sign": "stop_sign",
}

ACTOR_DEFAULT_SIZE = {  # (length along the heading, width across, height) in metres
    "pedestrian": (0.5, 0.6, 1.75),
    "car": (4.6, 1.9, 1.5),
    "animal": (1.0, 0.4, 0.8),
}
ACTOR_DEFAULT_HEADING = {"pedestrian": 90.0, "car": 0.0, "animal": 90.0}

_ID_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
_REQUIRED = object()


@dataclass(frozen=True)
class RoadSpec:
    """The road layout's dimensions.

    ``approach_length`` is the route length on a straight road, and the distance from the ego's start to
    the junction's entry (where its stop line is) otherwise; ``exit_length`` is how far the route goes past
    the junction. ``lanes`` counts the lanes in each direction (right-hand traffic). For a T-junction,
    ``junction_side`` says whether the ego drives on the through road (``"through"``, the stem on
    ``stem_side``) or arrives on the stem (``"dead_end"``, must turn). ``scenery`` adds buildings
    (``"urban"``) or houses and trees (``"suburban"``) beside the road.
    """

    approach_length: float = 120.0
    exit_length: float = 40.0
    lanes: int = 1
    lane_width: float = 3.5
    sidewalk_width: float = 3.0
    corner_radius: float = 6.0
    junction_side: str | None = None
    stem_side: str | None = None
    scenery: str = "plain"


@dataclass(frozen=True)
class EgoSpec:
    """The ego's start: its lane (0 = rightmost), initial speed, and ``cruise_onset``, the route position
    (of the ego's centre) where the run-up ends and cruising starts; Appendix A's distance *D* is the
    distance from there to the critical feature."""

    lane: int = 0
    speed: float = 0.0
    cruise_onset: float = 20.0


@dataclass(frozen=True)
class ActorSpec:
    """A road user: pedestrian, car or animal.

    ``s`` / ``offset`` place its centre (for ``motion = "cross"``, ``s`` is the crossing line and ``offset``
    where it starts; it walks across to ``end_offset`` and stands there). ``"along"`` walks along the route
    in the ``direction`` ``"same"`` as the ego or ``"opposite"``. A moving actor starts once the ego's
    front is within ``trigger_distance`` of it along the route (``None``: from the first step).
    ``heading_deg`` is the heading of a static actor relative to the route (90 = facing left).
    """

    id: str
    kind: str
    s: float
    offset: float = 0.0
    motion: str = "static"
    speed: float = 0.0
    direction: str | None = None
    end_offset: float | None = None
    trigger_distance: float | None = None
    heading_deg: float = 0.0
    length: float = 0.5
    width: float = 0.5
    height: float = 1.7


@dataclass(frozen=True)
class LightSpec:
    """A traffic light frozen to ``state``, governing the ego's lane at ``stop_line`` (route position)."""

    id: str = "tl0"
    state: str = "red"
    stop_line: float = 0.0


@dataclass(frozen=True)
class StopSignSpec:
    """A stop sign whose stop line is at ``stop_line`` (route position)."""

    id: str = "stop0"
    stop_line: float = 0.0


@dataclass(frozen=True)
class Scenario:
    """One scenario of the suite (or of a user's pack). Build with :func:`parse_scenario`."""

    id: str
    title: str
    family: str
    group: str
    blocking: bool | None
    layout: str
    command: str
    max_time_s: float
    source: Path | None = field(default=None, compare=False)
    road: RoadSpec = field(default_factory=RoadSpec)
    ego: EgoSpec = field(default_factory=EgoSpec)
    actors: tuple[ActorSpec, ...] = ()
    light: LightSpec | None = None
    stop_sign: StopSignSpec | None = None
    critical: str | None = None
    description: str = ""
    requires: tuple[str, ...] = ()

    @property
    def max_steps(self) -> int:
        """Episode length limit in 10 Hz steps."""
        return int(round(self.max_time_s / STEP_S))

    @property
    def critical_kind(self) -> str | None:
        """The actor kind of the critical feature (``traffic_light`` / ``stop_sign`` for road features)."""
        if self.critical is None:
            return None
        if self.light is not None and self.critical == self.light.id:
            return "traffic_light"
        if self.stop_sign is not None and self.critical == self.stop_sign.id:
            return "stop_sign"
        actor = self.actor(self.critical)
        return actor.kind if actor else None

    def actor(self, actor_id: str) -> ActorSpec | None:
        return next((a for a in self.actors if a.id == actor_id), None)

    def features(self) -> frozenset[str]:
        """What a simulator must be able to represent to run this scenario (plus ``requires``)."""
        found = {f"layout:{self.layout}", f"scenery:{self.road.scenery}", f"lanes:{self.road.lanes}"}
        for actor in self.actors:
            found.add(f"actor:{actor.kind}")
            found.add(f"motion:{actor.motion}")
        if self.light is not None:
            found.add(f"traffic_light:{self.light.state}")
        if self.stop_sign is not None:
            found.add("stop_sign")
        return frozenset(found | set(self.requires))

    def to_json(self) -> dict[str, Any]:
        """The full specification (defaults filled in); :func:`parse_scenario` reads it back unchanged."""
        out: dict[str, Any] = {}
        for f in fields(self):
            if f.name == "source":
                continue
            value = getattr(self, f.name)
            if value is None:
                continue
            if f.name == "actors":
                value = [_actor_json(a) for a in value]
            elif f.name == "road":
                value = _drop_none(vars(value))
                if self.layout == "straight":
                    del value["exit_length"]
            elif f.name in ("ego", "light", "stop_sign"):
                value = _drop_none(vars(value))
            elif f.name == "requires":
                value = list(value)
            out[f.name] = value
        return out

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: Path | str = "<mapping>") -> Scenario:
        return parse_scenario(data, source)


def _drop_none(values: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in values.items() if v is not None}


def _actor_json(actor: ActorSpec) -> dict[str, Any]:
    values = _drop_none(vars(actor))
    if actor.motion != "static":
        del values["heading_deg"]
    return values


# -- validation --------------------------------------------------------------------------------------


class _Table:
    """Reads typed fields from one mapping, failing with one line that names the file and the field."""

    def __init__(self, data: Any, where: str, prefix: str = ""):
        self.where, self.prefix = where, prefix
        if not isinstance(data, Mapping):
            target = f"field '{prefix.rstrip('.')}'" if prefix else "the file"
            raise ScenarioError(f"scenario {where}: {target} must be a table of fields, got {_show(data)}")
        self.data = data
        self.read: set[str] = set()

    def path(self, name: str) -> str:
        return f"{self.prefix}{name}"

    def fail(self, name: str, expected: str, value: Any) -> ScenarioError:
        return ScenarioError(f"scenario {self.where}: field '{self.path(name)}' must be {expected}, got {_show(value)}")

    def _raw(self, name: str, default: Any, expected: str) -> Any:
        self.read.add(name)
        if name in self.data:
            return self.data[name]
        if default is _REQUIRED:
            raise ScenarioError(f"scenario {self.where}: missing field '{self.path(name)}' ({expected})")
        return default

    def string(self, name: str, default: Any = _REQUIRED, choices: tuple[str, ...] | None = None,
               pattern: re.Pattern[str] | None = None) -> Any:
        expected = f"one of {', '.join(repr(c) for c in choices)}" if choices else "a non-empty string"
        value = self._raw(name, default, expected)
        if value is default and default is not _REQUIRED:
            return value
        if not isinstance(value, str) or not value.strip():
            raise self.fail(name, expected, value)
        if choices is not None and value not in choices:
            close = difflib.get_close_matches(value, choices, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ScenarioError(
                f"scenario {self.where}: field '{self.path(name)}' must be {expected}, got {_show(value)}{hint}"
            )
        if pattern is not None and not pattern.match(value):
            raise self.fail(name, "letters, digits, '.', '_' or '-' (no spaces or commas)", value)
        return value

    def text(self, name: str, default: str = "") -> str:
        value = self._raw(name, default, "a string")
        if not isinstance(value, str):
            raise self.fail(name, "a string", value)
        return value

    def number(self, name: str, default: Any = _REQUIRED, low: float | None = None, high: float | None = None,
               low_open: bool = False) -> Any:
        expected = _number_expectation(low, high, low_open)
        value = self._raw(name, default, expected)
        if value is default and default is not _REQUIRED:
            return value
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        if ok and low is not None:
            ok = value > low if low_open else value >= low
        if ok and high is not None:
            ok = value <= high
        if not ok:
            raise self.fail(name, expected, value)
        return float(value)

    def integer(self, name: str, default: Any = _REQUIRED, low: int = 0, high: int = 1_000_000) -> Any:
        expected = f"a whole number between {low} and {high}"
        value = self._raw(name, default, expected)
        if value is default and default is not _REQUIRED:
            return value
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
            raise self.fail(name, expected, value)
        return value

    def boolean(self, name: str, default: Any = _REQUIRED) -> Any:
        value = self._raw(name, default, "true or false")
        if value is default and default is not _REQUIRED:
            return value
        if not isinstance(value, bool):
            raise self.fail(name, "true or false", value)
        return value

    def table(self, name: str) -> _Table | None:
        value = self._raw(name, None, "a table")
        if value is None:
            return None
        return _Table(value, self.where, f"{self.path(name)}.")

    def tables(self, name: str) -> list[_Table]:
        value = self._raw(name, [], "a list of tables")
        if not isinstance(value, list):
            raise self.fail(name, "a list of tables ([[actors]] entries)", value)
        return [_Table(item, self.where, f"{self.path(name)}[{i}].") for i, item in enumerate(value)]

    def strings(self, name: str) -> tuple[str, ...]:
        value = self._raw(name, [], "a list of strings")
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
            raise self.fail(name, "a list of non-empty strings", value)
        return tuple(value)

    def done(self) -> None:
        """Fail on the first field nobody read: unknown fields are typos until proven otherwise."""
        for key in self.data:
            if key not in self.read:
                close = difflib.get_close_matches(str(key), sorted(self.read), n=1)
                hint = f"did you mean {close[0]!r}? " if close else ""
                allowed = ", ".join(sorted(self.read))
                raise ScenarioError(
                    f"scenario {self.where}: unknown field '{self.path(str(key))}' ({hint}allowed: {allowed})"
                )


def _number_expectation(low: float | None, high: float | None, low_open: bool) -> str:
    if low is not None and high is not None:
        return f"a number {'>' if low_open else '≥'} {_fmt(low)} and ≤ {_fmt(high)}"
    if low is not None:
        return f"a number {'>' if low_open else '≥'} {_fmt(low)}"
    return "a number"


def _fmt(value: float) -> str:
    return f"{value:g}"


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def parse_scenario(data: Mapping[str, Any], source: Path | str) -> Scenario:
    """Validate a scenario mapping (a parsed TOML/JSON file) and build the :class:`Scenario`.

    Raises :class:`~vladrivebench.errors.ScenarioError` with one line naming ``source``, the field and
    what is expected.
    """
    where = str(source)
    top = _Table(data, where)
    scenario_id = top.string("id", pattern=_ID_PATTERN)
    if scenario_id.lower() == "all":
        raise top.fail("id", "a name other than 'all' (reserved for selecting every scenario)", scenario_id)
    layout = top.string("layout", choices=LAYOUTS)
    road = _parse_road(top.table("road"), layout, top)
    values = dict(
        id=scenario_id,
        title=top.string("title"),
        family=top.string("family", choices=FAMILIES),
        group=top.string("group"),
        blocking=top.boolean("blocking", None),
        layout=layout,
        command=top.string("command", choices=NAV_COMMANDS),
        max_time_s=top.number("max_time_s", low=0.0, high=3600.0, low_open=True),
        description=top.text("description"),
        requires=top.strings("requires"),
        critical=top.string("critical", None),
        road=road,
    )
    values["ego"] = _parse_ego(top.table("ego"), road)
    values["actors"] = tuple(_parse_actor(t) for t in top.tables("actors"))
    values["light"] = _parse_light(top.table("light"), road, layout)
    values["stop_sign"] = _parse_stop_sign(top.table("stop_sign"), road, layout)
    top.done()
    scenario = Scenario(source=Path(source) if not isinstance(source, Path) else source, **values)
    _check_consistency(scenario, top)
    return scenario


def _parse_road(table: _Table | None, layout: str, top: _Table) -> RoadSpec:
    if table is None:
        raise ScenarioError(f"scenario {top.where}: missing table [road] (at least road.approach_length)")
    junction = layout != "straight"
    spec = RoadSpec(
        approach_length=table.number("approach_length", low=5.0, high=5000.0),
        exit_length=table.number("exit_length", RoadSpec.exit_length, low=5.0, high=5000.0),
        lanes=table.integer("lanes", RoadSpec.lanes, low=1, high=4),
        lane_width=table.number("lane_width", RoadSpec.lane_width, low=2.5, high=5.0),
        sidewalk_width=table.number("sidewalk_width", RoadSpec.sidewalk_width, low=0.0, high=10.0),
        corner_radius=table.number("corner_radius", RoadSpec.corner_radius, low=0.0, high=30.0),
        junction_side=table.string("junction_side", None, choices=JUNCTION_SIDES),
        stem_side=table.string("stem_side", None, choices=SIDES),
        scenery=table.string("scenery", RoadSpec.scenery, choices=SCENERIES),
    )
    table.done()
    if layout == "t_junction" and spec.junction_side is None:
        raise ScenarioError(
            f"scenario {top.where}: missing field 'road.junction_side' (a t_junction needs 'through' or 'dead_end')"
        )
    if layout != "t_junction" and spec.junction_side is not None:
        raise table.fail("junction_side", "absent unless layout = 't_junction'", spec.junction_side)
    if spec.stem_side is not None and spec.junction_side != "through":
        raise table.fail("stem_side", "absent unless road.junction_side = 'through'", spec.stem_side)
    if spec.junction_side == "through" and spec.stem_side is None:
        spec = replace(spec, stem_side="left")
    if not junction and "exit_length" in table.data:
        raise table.fail("exit_length", "absent on a straight road (the route is road.approach_length long)",
                         spec.exit_length)
    return spec


def _parse_ego(table: _Table | None, road: RoadSpec) -> EgoSpec:
    if table is None:
        return EgoSpec(cruise_onset=min(EgoSpec.cruise_onset, road.approach_length))
    spec = EgoSpec(
        lane=table.integer("lane", 0, low=0, high=road.lanes - 1),
        speed=table.number("speed", 0.0, low=0.0, high=40.0),
        cruise_onset=table.number("cruise_onset", EgoSpec.cruise_onset, low=0.0, high=road.approach_length),
    )
    table.done()
    return spec


def _parse_actor(table: _Table) -> ActorSpec:
    kind = table.string("kind", choices=ACTOR_SPEC_KINDS)
    motion = table.string("motion", "static", choices=MOTIONS)
    length, width, height = ACTOR_DEFAULT_SIZE[kind]
    moving = motion != "static"
    spec = ActorSpec(
        id=table.string("id", pattern=_ID_PATTERN),
        kind=kind,
        s=table.number("s", low=0.0),
        offset=table.number("offset", 0.0, low=-30.0, high=30.0),
        motion=motion,
        speed=table.number("speed", 0.0, low=0.0, high=30.0),
        direction=table.string("direction", None, choices=DIRECTIONS),
        end_offset=table.number("end_offset", None, low=-30.0, high=30.0),
        trigger_distance=table.number("trigger_distance", None, low=0.0),
        heading_deg=table.number("heading_deg", ACTOR_DEFAULT_HEADING[kind], low=-360.0, high=360.0),
        length=table.number("length", length, low=0.05, high=30.0),
        width=table.number("width", width, low=0.05, high=10.0),
        height=table.number("height", height, low=0.05, high=10.0),
    )
    table.done()
    if moving and spec.speed <= 0.0:
        raise table.fail("speed", f"a number > 0 for motion = {motion!r}", spec.speed)
    if not moving and spec.speed != 0.0:
        raise table.fail("speed", "0 (or absent) for a static actor", spec.speed)
    if (motion == "along") != (spec.direction is not None):
        expected = "'same' or 'opposite'" if motion == "along" else "absent unless motion = 'along'"
        raise table.fail("direction", expected, spec.direction)
    if motion == "cross":
        if spec.end_offset is None:
            raise table.fail("end_offset", "a number (where the crossing ends) for motion = 'cross'", None)
        if spec.end_offset == spec.offset:
            raise table.fail("end_offset", "different from 'offset' (the pedestrian must cross)", spec.end_offset)
    elif spec.end_offset is not None:
        raise table.fail("end_offset", "absent unless motion = 'cross'", spec.end_offset)
    if not moving and spec.trigger_distance is not None:
        raise table.fail("trigger_distance", "absent for a static actor", spec.trigger_distance)
    if moving and "heading_deg" in table.data:
        raise table.fail("heading_deg", "absent for a moving actor (it faces where it walks)", spec.heading_deg)
    return spec


def _stop_line(table: _Table, road: RoadSpec, layout: str) -> float:
    if layout == "straight":
        return table.number("stop_line", low=0.0, high=road.approach_length)
    value = table.number("stop_line", road.approach_length, low=0.0)
    if value != road.approach_length:
        raise table.fail("stop_line", f"the junction entry road.approach_length = {_fmt(road.approach_length)} "
                         "(or absent)", value)
    return value


def _parse_light(table: _Table | None, road: RoadSpec, layout: str) -> LightSpec | None:
    if table is None:
        return None
    spec = LightSpec(
        id=table.string("id", LightSpec.id, pattern=_ID_PATTERN),
        state=table.string("state", choices=LIGHT_COLOURS),
        stop_line=_stop_line(table, road, layout),
    )
    table.done()
    return spec


def _parse_stop_sign(table: _Table | None, road: RoadSpec, layout: str) -> StopSignSpec | None:
    if table is None:
        return None
    spec = StopSignSpec(
        id=table.string("id", StopSignSpec.id, pattern=_ID_PATTERN),
        stop_line=_stop_line(table, road, layout),
    )
    table.done()
    return spec


def allowed_commands(layout: str, road: RoadSpec) -> tuple[str, ...]:
    """The navigation commands a route through this layout can follow."""
    if layout == "straight":
        return ("follow_lane", "straight")
    if layout == "four_way":
        return ("straight", "left", "right")
    if road.junction_side == "dead_end":
        return ("left", "right")
    return ("straight", road.stem_side or "left")


ACTOR_BEYOND_ROUTE = 20.0
"""How far (m) past the end of the route an actor may stand (a car parked just beyond it, say)."""


def route_length(layout: str, road: RoadSpec) -> float:
    """The length of the ego's route: the approach, plus the exit road past a junction."""
    return road.approach_length + (road.exit_length if layout != "straight" else 0.0)


def _check_actors_on_route(sc: Scenario, where: str) -> None:
    limit = route_length(sc.layout, sc.road) + ACTOR_BEYOND_ROUTE
    for index, actor in enumerate(sc.actors):
        if actor.s > limit:
            raise ScenarioError(
                f"scenario {where}: field 'actors[{index}].s' (actor {actor.id!r}) must be at most {_fmt(limit)} "
                f"(the route is {_fmt(route_length(sc.layout, sc.road))} m long), got {_fmt(actor.s)}: "
                f"an actor beyond the end of the road is never met")


def _check_consistency(sc: Scenario, top: _Table) -> None:
    where = top.where
    ids = [a.id for a in sc.actors]
    ids += [sc.light.id] if sc.light else []
    ids += [sc.stop_sign.id] if sc.stop_sign else []
    duplicate = next((i for i in ids if ids.count(i) > 1), None)
    if duplicate is not None:
        raise ScenarioError(f"scenario {where}: id {duplicate!r} is used by two actors/features; ids must be unique")
    _check_actors_on_route(sc, where)
    commands = allowed_commands(sc.layout, sc.road)
    if sc.command not in commands:
        raise top.fail("command", f"one of {', '.join(repr(c) for c in commands)} for this layout", sc.command)
    if sc.critical is not None and sc.critical not in ids:
        raise top.fail("critical", f"the id of an actor or feature of this scenario ({', '.join(ids) or 'none'})",
                       sc.critical)
    expected_kind = FAMILY_CRITICAL_KIND.get(sc.family)
    if expected_kind is not None and sc.critical_kind != expected_kind:
        raise top.fail("critical", f"the id of a {expected_kind.replace('_', ' ')} (family {sc.family!r})",
                       sc.critical)
    if sc.family == "baseline" and (sc.critical is not None or sc.actors):
        raise ScenarioError(f"scenario {where}: a 'baseline' scenario has no actors and no critical feature")


# -- loading -----------------------------------------------------------------------------------------

SCENARIO_SUFFIXES = (".toml", ".json")


def load_scenario_file(path: Path | str) -> Scenario:
    """Read and validate one scenario file (TOML or JSON)."""
    from vladrivebench._engine.options import load_data_file

    path = Path(path)
    if path.suffix.lower() not in SCENARIO_SUFFIXES:
        raise ScenarioError(f"scenario {path}: expected a .toml or .json file")
    try:
        data = load_data_file(path, "scenario")
    except ConfigError as exc:
        raise ScenarioError(str(exc)) from None
    return parse_scenario(data, path)


def scenario_files(path: Path) -> list[Path]:
    """The scenario files of a registered path: the file itself, or a directory's TOML/JSON files."""
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.suffix.lower() in SCENARIO_SUFFIXES and p.is_file())
    return [path]


def load_suite(registry: Any = None) -> dict[str, Scenario]:
    """Every scenario of every registered file or directory, by id, in natural id order."""
    from vladrivebench._engine.registry import get_registry

    registry = registry if registry is not None else get_registry()
    found: dict[str, Scenario] = {}
    for comp in registry.components("scenario"):
        path = Path(comp.path or comp.name)
        if not path.exists():
            _pack_failure(registry, comp, ScenarioError(
                f"scenario pack {path} (registered by plugin {comp.plugin!r}): no such file or directory"))
            continue
        for file in scenario_files(path):
            try:
                scenario = load_scenario_file(file)
            except ScenarioError as exc:
                _pack_failure(registry, comp, exc)
                continue
            previous = found.get(scenario.id)
            if previous is not None:
                raise ScenarioError(
                    f"scenario id {scenario.id!r} is defined twice: in {previous.source} and in {file}"
                )
            found[scenario.id] = scenario
    return {k: found[k] for k in sorted(found, key=natural_key)}


def _pack_failure(registry: Any, comp: Any, exc: ScenarioError) -> None:
    """A broken file of a plugin's scenario pack: the plugin is marked failing (``vdb list-plugins`` shows the
    file and the reason) and its other scenarios still resolve. The core's own suite, or strict plugins, fail."""
    if comp.plugin == "core" or getattr(registry, "strict", False):
        raise exc
    for info in getattr(registry, "plugins", ()):
        if info.name == comp.plugin:
            first = " ".join(str(exc).split())
            if info.status != "error":
                info.status, info.error = "error", first
            elif first not in (info.error or ""):
                info.error = f"{info.error}; {first}"


def check_scenario_packs(registry: Any) -> None:
    """Load every registered scenario pack once, so that broken files show as plugin failures."""
    try:
        load_suite(registry)
    except ScenarioError:
        pass  # a duplicate id or a broken core file: the commands that read scenarios say it in one line


def natural_key(text: str) -> tuple:
    """Sort key where digits compare as numbers: P.2 < P.10."""
    return tuple((0, int(part), "") if part.isdigit() else (1, 0, part) for part in re.split(r"(\d+)", text) if part)


def resolve_scenarios(spec: str | list[str] | tuple[str, ...], registry: Any = None) -> list[Scenario]:
    """Select scenarios: ``"all"``, ids (``"P.1,C.1"``), families (``"pedestrian"``), globs (``"TL.*"``)
    or paths of scenario files. Order is kept, duplicates dropped; an unknown name raises
    :class:`~vladrivebench.errors.UnknownNameError` with suggestions."""
    tokens = [t.strip() for t in (spec.split(",") if isinstance(spec, str) else spec)]
    tokens = [t for t in tokens if t]
    if not tokens:
        raise ConfigError("no scenarios selected: give ids (P.1,C.1), a family (pedestrian), a glob (TL.*) or 'all'")
    suite: dict[str, Scenario] | None = None
    chosen: dict[str, Scenario] = {}
    files = [t for t in tokens if _is_file_token(t)]
    if files:
        suite = load_suite(registry)
    for token in tokens:
        if token in files:
            scenario = load_scenario_file(token)
            _check_not_redefined(scenario, chosen, suite or {})
            chosen.setdefault(scenario.id, scenario)
            continue
        suite = suite if suite is not None else load_suite(registry)
        for scenario in _select(token, suite):
            chosen.setdefault(scenario.id, scenario)
    return list(chosen.values())


def _is_file_token(token: str) -> bool:
    """A token naming a file (``my/x.toml``, ``x.yaml``) rather than an id, a family or a glob."""
    path = Path(token)
    return (token.lower().endswith(SCENARIO_SUFFIXES) or "/" in token or "\\" in token
            or (path.suffix.lower() in OTHER_DATA_SUFFIXES) or path.is_file())


OTHER_DATA_SUFFIXES = (".yaml", ".yml", ".ini", ".txt", ".csv", ".xml", ".cfg")


def _check_not_redefined(scenario: Scenario, chosen: dict[str, Scenario], suite: dict[str, Scenario]) -> None:
    for other in (chosen.get(scenario.id), suite.get(scenario.id)):
        if other is not None and _source_of(other) != _source_of(scenario):
            raise ScenarioError(f"scenario id {scenario.id!r} is defined twice: in {other.source} and in "
                                f"{scenario.source}; give one of them another id")


def _source_of(scenario: Scenario) -> str:
    try:
        return str(Path(scenario.source).resolve())
    except (OSError, TypeError):
        return str(scenario.source)


def _select(token: str, suite: dict[str, Scenario]) -> list[Scenario]:
    if token.lower() == "all":
        return list(suite.values())
    if token in suite:
        return [suite[token]]
    if token in FAMILIES:
        return [s for s in suite.values() if s.family == token]
    if any(ch in token for ch in "*?["):
        matches = [s for s in suite.values() if fnmatch.fnmatchcase(s.id, token)]
        if matches:
            return matches
    raise UnknownNameError("scenario", token, list(suite) + [f for f in FAMILIES if any(
        s.family == f for s in suite.values())])


def scenario_summary(scenario: Scenario) -> dict[str, Any]:
    """The row ``vdb scenarios`` shows for one scenario."""
    return {
        "id": scenario.id,
        "title": scenario.title,
        "family": scenario.family,
        "group": scenario.group,
        "layout": scenario.layout,
        "command": scenario.command,
        "critical": scenario.critical_kind,
        "source": str(scenario.source) if scenario.source else None,
    }


def dumps(scenario: Scenario) -> str:
    """The scenario as indented JSON (a valid scenario file)."""
    return json.dumps(scenario.to_json(), indent=2)
