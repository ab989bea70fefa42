"""Tests for cellsim.config.typed_yaml: typed YAML loading with line-numbered errors."""

from __future__ import annotations

import copy
import enum
import pickle
from dataclasses import dataclass, field
from typing import Literal

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cellsim.config.typed_yaml import (
    ConfigError,
    FieldError,
    Loaded,
    apply_override,
    apply_overrides,
    dump_yaml,
    from_data,
    load_file,
    load_text,
    to_data,
)

# --------------------------------------------------------------------------- test schema


class Mode(enum.Enum):
    MODEL = "model"
    SHADOW = "shadow"
    TWIN = "twin"


@dataclass
class Waypoint:
    position: tuple[float, float, float]
    wait: float = 0.0
    reach: float | None = None


@dataclass
class Robot:
    kind: Literal["robot"]
    name: str
    payload: float = 0.0
    max_payload: float = 5.0
    joints: int = 6
    enabled: bool = True

    def __post_init__(self) -> None:
        if self.payload > self.max_payload:
            raise FieldError("max_payload", f"is below the payload ({self.payload} kg)")


@dataclass
class Operator:
    kind: Literal["operator"] = "operator"
    mode: Mode = Mode.MODEL
    speed: float = field(default=1.2, metadata={"doc": "walking speed", "unit": "m/s"})
    waypoints: dict[str, Waypoint] = field(default_factory=dict)
    route: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.speed <= 0:
            raise FieldError("speed", "must be positive")
        for name, wp in self.waypoints.items():
            if wp.reach is not None and wp.reach > 2.0:
                raise FieldError(f"waypoints.{name}.reach", "beyond arm's reach (2.0 m)")
        for name in self.route:
            if name not in self.waypoints:
                raise ValueError(f"route visits unknown waypoint '{name}'")


@dataclass
class Scenario:
    name: str
    twin: Mode
    entities: dict[str, Robot | Operator]
    tags: tuple[str, ...] = ()
    seed: int = 0
    stage: Literal["draft", "final"] = "draft"


VALID = """\
name: demo
twin: shadow
entities:
  arm:
    kind: robot
    name: ur5
    payload: 3
  operator:
    kind: operator
    mode: twin
    waypoints:
      bench:
        position: [1, 2.5, 0]
        wait: 2
      cell:
        position: [0, 0, 0]
    route:
      - bench
      - cell
tags: [a, b]
"""


def edit(line: int, new: str | None, count: int = 1) -> str:
    """VALID with ``count`` lines from 1-based ``line`` replaced by ``new`` (None: removed)."""
    lines = VALID.splitlines()
    assert 1 <= line <= len(lines) - count + 1
    lines[line - 1 : line - 1 + count] = [] if new is None else [new]
    return "\n".join(lines) + "\n"


def error_of(text: str, schema: type = Scenario) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load_text(schema, text, source="s.yaml")
    return info.value


def assert_error(err: ConfigError, line: int | None, key: str, problem: str) -> None:
    assert (err.source, err.line, err.key, err.problem) == ("s.yaml", line, key, problem), str(err)


# --------------------------------------------------------------------------- valid loads


def test_valid_load_values_and_lines() -> None:
    loaded = load_text(Scenario, VALID, source="s.yaml")
    s = loaded.value
    assert loaded.source == "s.yaml"
    assert s.twin is Mode.SHADOW and s.tags == ("a", "b") and s.seed == 0 and s.stage == "draft"
    assert list(s.entities) == ["arm", "operator"]
    arm, op = s.entities["arm"], s.entities["operator"]
    assert isinstance(arm, Robot) and isinstance(op, Operator)
    assert arm.payload == 3.0 and type(arm.payload) is float and arm.joints == 6
    assert op.mode is Mode.TWIN and op.speed == 1.2 and op.route == ["bench", "cell"]
    assert list(op.waypoints) == ["bench", "cell"]
    assert op.waypoints["bench"] == Waypoint(position=(1.0, 2.5, 0.0), wait=2.0)
    assert all(type(c) is float for c in op.waypoints["bench"].position)

    lines = loaded.lines
    assert lines[""] == 1 and lines["twin"] == 2 and lines["entities.arm.payload"] == 7
    assert lines["entities.operator.waypoints.bench.wait"] == 14
    assert lines["entities.operator.waypoints.cell"] == 15
    assert lines["entities.operator.route.0"] == 18 and lines["entities.operator.route.1"] == 19
    assert lines["tags.1"] == 20
    # Omitted keys fall back to the nearest written ancestor.
    assert loaded.line_of("entities.operator.speed") == 8
    assert loaded.line_of("entities.operator.waypoints.cell.wait") == 15
    assert loaded.line_of("nothing.here") == 1


def test_load_file_and_unreadable_file(tmp_path) -> None:
    path = tmp_path / "x.yaml"
    path.write_text(edit(14, "        wait: abc"), encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_file(Scenario, path)
    assert str(info.value) == (f"{path}:14: entities.operator.waypoints.bench.wait: "
                               "expected a number, got 'abc'")
    path.write_text(VALID, encoding="utf-8")
    assert load_file(Scenario, str(path)).source == str(path)

    missing = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError) as info:
        load_file(Scenario, missing)
    err = info.value
    assert (err.source, err.line, err.key) == (str(missing), None, "")
    assert err.problem.startswith("cannot read file: ") and "No such file" in err.problem


def test_config_error_formatting_and_pickling() -> None:
    assert str(ConfigError("a.yaml", 3, "x.y", "bad")) == "a.yaml:3: x.y: bad"
    assert str(ConfigError("--set", None, "x.y", "bad")) == "--set: x.y: bad"
    assert str(ConfigError("a.yaml", 1, "", "bad")) == "a.yaml:1: bad"
    err = pickle.loads(pickle.dumps(ConfigError("a.yaml", 3, "x.y", "bad")))
    assert (err.line, err.key, str(err)) == (3, "x.y", "a.yaml:3: x.y: bad")
    assert issubclass(FieldError, ValueError)


def test_anchors_and_merge_keys() -> None:
    text = (
        "name: demo\ntwin: model\nentities:\n"
        "  op:\n    kind: operator\n    waypoints:\n"
        "      a: &base {position: [1, 1, 1], wait: 3}\n"
        "      b:\n        <<: *base\n        wait: 5\n"
    )
    wps = load_text(Scenario, text).value.entities["op"].waypoints
    assert wps["a"] == Waypoint((1.0, 1.0, 1.0), 3.0)
    assert wps["b"] == Waypoint((1.0, 1.0, 1.0), 5.0)

    err = error_of("name: &a [*a]\ntwin: model\nentities: {}\n")
    assert (err.line, err.problem) == (1, "recursive YAML alias")


# --------------------------------------------------------------------------- error cases


def test_malformed_yaml() -> None:
    err = error_of(edit(13, "        position: [1, 2.5, 0"))
    assert err.line == 14 and err.key == "" and err.problem.startswith("malformed YAML: ")
    err = error_of(edit(6, "    name: ur5: x"))
    assert err.line == 6 and err.problem.startswith("malformed YAML: ")
    err = error_of(edit(6, "    name: u\x01r5"))  # reader errors have a position, not a mark
    assert err.line == 6 and err.problem.startswith("malformed YAML: unacceptable character #x0001")
    err = error_of(VALID + "---\nname: again\n")
    assert err.line == 21 and "single document" in err.problem
    err = error_of("name: " + "[" * 5000 + "]" * 5000)
    assert (err.line, err.problem) == (1, "malformed YAML: nested deeper than 100 levels")
    err = error_of(edit(6, "    name: !custom ur5"))
    assert err.line == 6 and err.key == "entities.arm.name"
    assert err.problem.startswith("malformed YAML: ")


@pytest.mark.parametrize("text,line,problem", [
    ("", 1, "empty document (expected a mapping)"),
    ("# only a comment\n", 1, "empty document (expected a mapping)"),
    ("\n\n- a\n- b\n", 3, "expected a mapping at the top level, got a list"),
    ("just text\n", 1, "expected a mapping at the top level, got 'just text'"),
])
def test_document_not_a_mapping(text: str, line: int, problem: str) -> None:
    assert_error(error_of(text), line, "", problem)


def test_duplicate_key() -> None:
    err = error_of(edit(16, "        position: [0, 0, 0]\n        position: [1, 1, 1]"))
    assert_error(err, 17, "entities.operator.waypoints.cell.position",
                 "duplicate key 'position' (first given on line 16)")
    err = error_of(VALID + "name: again\n")
    assert_error(err, 21, "name", "duplicate key 'name' (first given on line 1)")


def test_unknown_key() -> None:
    assert_error(error_of(edit(14, "        waitt: 2")), 14,
                 "entities.operator.waypoints.bench.waitt",
                 "unknown key 'waitt' (expected one of: position, wait, reach); did you mean 'wait'?")
    assert_error(error_of(VALID + "zzz: 1\n"), 21, "zzz",
                 "unknown key 'zzz' (expected one of: name, twin, entities, tags, seed, stage)")


def test_missing_required_key() -> None:
    assert_error(error_of(edit(16, "        wait: 1")), 15, "entities.operator.waypoints.cell",
                 "missing required key 'position'")
    # At the top level, the line where the document's mapping starts.
    assert_error(error_of(edit(1, "# no name")), 2, "", "missing required key 'name'")


@pytest.mark.parametrize("line,new,key,problem", [  # new text replaces `line` and its children
    (14, "        wait: abc", "entities.operator.waypoints.bench.wait", "expected a number, got 'abc'"),
    (14, "        wait: true", "entities.operator.waypoints.bench.wait", "expected a number, got 'true'"),
    (14, "        wait:", "entities.operator.waypoints.bench.wait", "expected a number, got null"),
    (14, "        wait: 1" + "0" * 400, "entities.operator.waypoints.bench.wait",
     "number too large: '" + "1" + "0" * 59 + "...'"),
    (14, "        wait: 1e3", "entities.operator.waypoints.bench.wait",
     "expected a number, got '1e3' (YAML reads it as text; write e.g. 1.0e+3)"),
    (7, "    enabled: 3", "entities.arm.enabled", "expected true or false, got '3'"),
    (7, "    joints: 6.5", "entities.arm.joints", "expected an integer, got '6.5'"),
    (7, "    joints: yes", "entities.arm.joints", "expected an integer, got 'yes'"),
    (6, "    name: 42", "entities.arm.name", "expected a string, got '42' (put it in quotes)"),
    (6, "    name: 12", "entities.arm.name", "expected a string, got '12' (put it in quotes)"),
    (11, "    waypoints: []\n#6", "entities.operator.waypoints", "expected a mapping, got a list"),
    (17, "    route: bench\n#3", "entities.operator.route", "expected a list, got 'bench'"),
    (13, "        position: {x: 1}", "entities.operator.waypoints.bench.position",
     "expected a list, got a mapping"),
    (13, "        position: [1, x, 0]", "entities.operator.waypoints.bench.position.1",
     "expected a number, got 'x'"),
    (13, "        position: [1, 2]", "entities.operator.waypoints.bench.position",
     "expected a list of 3 items, got 2"),
    (2, "twin: shadw", "twin", "'shadw' is not one of: model, shadow, twin"),
    (10, "    mode: 3", "entities.operator.mode", "'3' is not one of: model, shadow, twin"),
    (20, "stage: finale", "stage", "'finale' is not one of: draft, final"),
    (20, "tags: [a, 3]", "tags.1", "expected a string, got '3' (put it in quotes)"),
    (12, "      1:", "entities.operator.waypoints.1",
     "keys must be strings, got '1' (put it in quotes)"),
    (5, "    kind: robt", "entities.arm.kind",
     "unknown kind 'robt' (expected one of: robot, operator); did you mean 'robot'?"),
])
def test_wrong_values(line: int, new: str, key: str, problem: str) -> None:
    new, _, count = new.partition("\n#")
    assert_error(error_of(edit(line, new, int(count or 1))), line, key, problem)


def test_problem_is_one_line() -> None:
    err = error_of(edit(6, '    name: "ur5"\n    joints: "six\\nseven"'))
    assert str(err) == r"s.yaml:7: entities.arm.joints: expected an integer, got 'six\nseven'"


def test_missing_kind_and_non_mapping_union() -> None:
    assert_error(error_of(edit(5, None)), 4, "entities.arm",
                 "missing required key 'kind' (one of: robot, operator)")
    assert_error(error_of(edit(4, "  arm: 3", count=4)), 4, "entities.arm", "expected a mapping, got '3'")


def test_post_init_errors() -> None:
    # FieldError on a written field: that field's line.
    text = edit(10, "    mode: twin\n    speed: -1")
    assert_error(error_of(text), 11, "entities.operator.speed", "must be positive")
    # FieldError with a dotted sub-path.
    text = edit(14, "        wait: 2\n        reach: 3")
    assert_error(error_of(text), 15, "entities.operator.waypoints.bench.reach",
                 "beyond arm's reach (2.0 m)")
    # FieldError on an omitted field: the mapping's line.
    assert_error(error_of(edit(7, "    payload: 9")), 4, "entities.arm.max_payload",
                 "is below the payload (9.0 kg)")
    # Any other ValueError: the mapping's line and key.
    assert_error(error_of(edit(19, "      - nope")), 8, "entities.operator",
                 "route visits unknown waypoint 'nope'")


def test_from_data_errors_have_no_line() -> None:
    value = from_data(Waypoint, {"position": [1, 2, 3]})
    assert value == Waypoint((1.0, 2.0, 3.0))
    with pytest.raises(ConfigError) as info:
        from_data(Scenario, {"name": "x", "twin": "model", "entities": {"o": {"kind": "operator",
                                                                         "speed": "fast"}}})
    assert str(info.value) == "<data>: entities.o.speed: expected a number, got 'fast'"


# --------------------------------------------------------------------------- to_data / dump_yaml


def test_to_data_is_fully_resolved() -> None:
    s = load_text(Scenario, VALID).value
    data = to_data(s)
    assert list(data) == ["name", "twin", "entities", "tags", "seed", "stage"]
    assert data["twin"] == "shadow" and data["tags"] == ["a", "b"] and data["seed"] == 0
    assert data["entities"]["arm"] == {"kind": "robot", "name": "ur5", "payload": 3.0,
                                       "max_payload": 5.0, "joints": 6, "enabled": True}
    op = data["entities"]["operator"]
    assert op["speed"] == 1.2 and op["mode"] == "twin"
    assert op["waypoints"]["cell"] == {"position": [0.0, 0.0, 0.0], "wait": 0.0, "reach": None}


def test_dump_yaml_round_trip_and_header() -> None:
    s = load_text(Scenario, VALID).value
    text = dump_yaml(s, header="resolved scenario\n\nfrom s.yaml")
    assert text.startswith("# resolved scenario\n#\n# from s.yaml\nname: demo\n")
    assert "speed: 1.2" in text and "max_payload: 5.0" in text
    assert load_text(Scenario, text).value == s
    assert yaml.safe_load(dump_yaml(s)) == to_data(s)


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
names = st.text(min_size=1, max_size=8)
waypoints = st.builds(Waypoint, position=st.tuples(finite, finite, finite), wait=finite,
                      reach=st.none() | st.floats(-5, 2))
robots = st.builds(Robot, kind=st.just("robot"), name=st.text(max_size=12),
                   payload=st.floats(-10, 5), max_payload=st.just(5.0),
                   joints=st.integers(-2**40, 2**40), enabled=st.booleans())


@st.composite
def operators(draw) -> Operator:
    wps = draw(st.dictionaries(names, waypoints, max_size=3))
    route = draw(st.lists(st.sampled_from(sorted(wps)), max_size=4)) if wps else []
    return Operator(mode=draw(st.sampled_from(Mode)), speed=draw(st.floats(0.01, 1e6)),
                    waypoints=wps, route=route)


scenarios = st.builds(Scenario, name=st.text(max_size=12), twin=st.sampled_from(Mode),
                      entities=st.dictionaries(names, robots | operators(), max_size=3),
                      tags=st.lists(st.text(max_size=5), max_size=3).map(tuple),
                      seed=st.integers(), stage=st.sampled_from(["draft", "final"]))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenarios)
def test_round_trip_generated(s: Scenario) -> None:
    assert load_text(Scenario, dump_yaml(s, header="generated")).value == s
    assert from_data(Scenario, to_data(s)) == s


@settings(max_examples=150, deadline=None)
@given(st.sampled_from(range(1, 21)), st.text(max_size=30))
def test_no_other_exception_escapes(line: int, junk: str) -> None:
    """Arbitrary damage to a valid file gives a ConfigError or a value, never a crash."""
    lines = VALID.splitlines()
    indent = lines[line - 1][: len(lines[line - 1]) - len(lines[line - 1].lstrip())]
    key = lines[line - 1].strip().split(":")[0]
    for text in (edit(line, indent + junk), edit(line, f"{indent}{key}: {junk}"), junk):
        try:
            load_text(Scenario, text)
        except ConfigError as e:
            assert "\n" not in str(e) and str(e).startswith("<text>:")


# --------------------------------------------------------------------------- apply_override


@pytest.fixture
def loaded() -> Loaded[Scenario]:
    return load_text(Scenario, VALID, source="s.yaml")


def test_override_nested_dict_key(loaded) -> None:
    apply_override(loaded, "entities.operator.waypoints.bench.wait=4.5")
    assert loaded.value.entities["operator"].waypoints["bench"].wait == 4.5
    apply_override(loaded, "entities.operator.waypoints.cell.position = [1, 2, 3]")
    assert loaded.value.entities["operator"].waypoints["cell"].position == (1.0, 2.0, 3.0)
    apply_override(loaded, "entities.operator.waypoints.cell.position.2=7")
    assert loaded.value.entities["operator"].waypoints["cell"].position == (1.0, 2.0, 7.0)


def test_override_omitted_default_enum_and_int(loaded) -> None:
    apply_override(loaded, "entities.operator.speed=4")
    op = loaded.value.entities["operator"]
    assert op.speed == 4.0 and type(op.speed) is float
    apply_override(loaded, "twin=model")
    apply_override(loaded, "seed=17")
    apply_override(loaded, "entities.arm.enabled=false")
    assert loaded.value.twin is Mode.MODEL and loaded.value.seed == 17
    assert loaded.value.entities["arm"].enabled is False
    assert loaded.value.entities["operator"].speed == 4.0  # earlier overrides kept


def test_override_list_index_and_substructure(loaded) -> None:
    apply_override(loaded, "entities.operator.route.0=cell")
    assert loaded.value.entities["operator"].route == ["cell", "cell"]
    apply_override(loaded, "entities.operator.waypoints.cell={position: [5, 5, 5], wait: 1}")
    assert loaded.value.entities["operator"].waypoints["cell"] == Waypoint((5.0, 5.0, 5.0), 1.0)
    apply_override(loaded, "entities.arm={kind: robot, name: ur10, payload: 4}")
    assert loaded.value.entities["arm"] == Robot(kind="robot", name="ur10", payload=4.0)


def test_override_resolve_shortcut(loaded) -> None:
    seen = []

    def resolve(parts: list[str]) -> list[str]:
        seen.append(list(parts))
        return ["entities", *parts] if parts[0] in loaded.value.entities else parts

    apply_override(loaded, "operator.waypoints.bench.wait=9", resolve=resolve)
    apply_override(loaded, "seed=3", resolve=resolve)
    assert seen == [["operator", "waypoints", "bench", "wait"], ["seed"]]
    assert loaded.value.entities["operator"].waypoints["bench"].wait == 9.0
    assert loaded.value.seed == 3
    with pytest.raises(ConfigError) as info:
        apply_override(loaded, "operator.sped=1", resolve=resolve)
    assert info.value.key == "entities.operator.sped"


@pytest.mark.parametrize("assignment,key,problem", [
    ("entities.operator.speed", "entities.operator.speed",
     "malformed override 'entities.operator.speed' (expected dotted.path=value)"),
    ("entities..speed=1", "entities..speed",
     "malformed override 'entities..speed=1' (expected dotted.path=value)"),
    ("entities.operator.sped=2", "entities.operator.sped",
     "no such configuration point; did you mean 'entities.operator.speed'?"),
    ("entities.operator.waypoints.new.wait=1", "entities.operator.waypoints.new.wait",
     "no such configuration point (options at 'entities.operator.waypoints': bench, cell)"),
    ("entities.operatr.speed=2", "entities.operatr.speed",
     "no such configuration point; did you mean 'entities.operator'?"),
    ("zzz=2", "zzz", "no such configuration point "
     "(options at 'top level': name, twin, entities, tags, seed, stage)"),
    ("entities.operator.route.5=cell", "entities.operator.route.5",
     "no such configuration point ('entities.operator.route' is a list of 2 items, indexed from 0)"),
    ("entities.operator.speed.x=1", "entities.operator.speed.x",
     "no such configuration point ('entities.operator.speed' is a single value, not a mapping)"),
    ("entities.operator.waypoints.bench.reach.x=1", "entities.operator.waypoints.bench.reach.x",
     "no such configuration point ('entities.operator.waypoints.bench.reach' is not set (null))"),
    ("entities.operator.speed=abc", "entities.operator.speed", "expected a number, got 'abc'"),
    ("entities.operator.speed=[1", "entities.operator.speed",
     "malformed value '[1': while parsing a flow sequence; did not find expected ',' or ']'"),
    ("entities.operator.mode=shadw", "entities.operator.mode",
     "'shadw' is not one of: model, shadow, twin"),
    ("entities.operator.waypoints.bench.position=[1, 2]",
     "entities.operator.waypoints.bench.position", "expected a list of 3 items, got 2"),
    ("entities.operator.waypoints.bench={wait: 1}", "entities.operator.waypoints.bench",
     "missing required key 'position'"),
    ("entities.operator.speed=-1", "entities.operator.speed", "must be positive"),
    ("entities.arm.payload=50", "entities.arm.payload",
     "is below the payload (50.0 kg) (at entities.arm.max_payload)"),
    ("entities.operator.route.0=nope", "entities.operator.route.0",
     "route visits unknown waypoint 'nope' (at entities.operator)"),
])
def test_override_errors_leave_value_unchanged(loaded, assignment: str, key: str,
                                               problem: str) -> None:
    before, snapshot = loaded.value, copy.deepcopy(loaded.value)
    with pytest.raises(ConfigError) as info:
        apply_override(loaded, assignment)
    err = info.value
    assert (err.source, err.line, err.key, err.problem) == ("--set", None, key, problem), str(err)
    assert loaded.value is before and loaded.value == snapshot


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=40))
def test_override_never_crashes(assignment: str) -> None:
    loaded = load_text(Scenario, VALID)
    before = copy.deepcopy(loaded.value)
    try:
        apply_override(loaded, "entities.operator." + assignment)
    except ConfigError:
        assert loaded.value == before


def test_yaml_12_booleans_keep_on_off_yes_no_as_words():
    """Cell vocabularies use ``off`` (welder activity): only true/false are booleans."""
    from cellsim.config.typed_yaml import _parse

    data, _, _ = _parse("a: off\nb: on\nc: no\nd: yes\ne: true\nf: False\n", "<t>")
    assert data == {"a": "off", "b": "on", "c": "no", "d": "yes", "e": True, "f": False}


def test_overrides_at_once_equal_overrides_one_by_one(loaded) -> None:
    sets = ["entities.operator.waypoints.bench.wait=4.5", "seed=17", "entities.arm.payload=4"]
    one_by_one = load_text(Scenario, VALID, source="s.yaml")
    for assignment in sets:
        apply_override(one_by_one, assignment)
    apply_overrides(loaded, sets)
    assert loaded.value == one_by_one.value


def test_overrides_at_once_name_the_one_at_fault(loaded) -> None:
    before = loaded.value
    # each is fine alone against the file; together the payload exceeds the maximum
    with pytest.raises(ConfigError) as e:
        apply_overrides(loaded, ["seed=3", "entities.arm.max_payload=2", "entities.arm.payload=4.5"])
    assert e.value.key == "entities.arm.max_payload" and "below the payload" in e.value.problem
    assert loaded.value.entities["arm"].max_payload == before.entities["arm"].max_payload


def test_overrides_at_once_see_the_structure_earlier_ones_create(loaded) -> None:
    apply_overrides(loaded, ["entities.operator.route=[bench, cell, bench]", "entities.operator.route.2=cell"])
    assert loaded.value.entities["operator"].route == ["bench", "cell", "cell"]


# --------------------------------------------------------------------------- valid ranges and bounds

from typing import Annotated  # noqa: E402

from cellsim.config import typed_yaml  # noqa: E402
from cellsim.config.typed_yaml import Range, range_of, type_at  # noqa: E402

Pos = Annotated[tuple[float, float, float], Range(-10.0, 10.0, unit="m")]


@dataclass
class Ranged:
    period: Annotated[float, Range(0.0, 1.0, lo_open=True, unit="s")] = 0.5
    count: Annotated[int, Range(1, 10)] = 1
    where: Pos = (0.0, 0.0, 0.0)
    reach: Pos | None = None
    poses: dict[str, list[Annotated[float, Range(-1.0, 1.0, unit="rad")]]] = field(default_factory=dict)
    free: float = 0.0


@pytest.mark.parametrize(
    "text, line, key, problem",
    [
        ("period: 0\n", 1, "period", "'0' is out of range: must be in (0, 1] s"),
        ("free: 1\nperiod: 1.5\n", 2, "period", "'1.5' is out of range: must be in (0, 1] s"),
        ("period: .nan\n", 1, "period", "expected a finite number, got '.nan'"),
        ("free: -.inf\n", 1, "free", "expected a finite number, got '-.inf'"),
        ("count: 0\n", 1, "count", "'0' is out of range: must be in [1, 10]"),
        ("count: 99999999999999999999\n", 1, "count", "is out of range: must be in [1, 10]"),
        ("where: [0, 11, 0]\n", 1, "where.1", "'11' is out of range: must be in [-10, 10] m"),
        ("where: [0, .inf, 0]\n", 1, "where.1", "expected a finite number, got '.inf'"),
        ("reach:\n  - 0\n  - 0\n  - -20\n", 4, "reach.2", "'-20' is out of range"),
        ("poses:\n  a: [0, 2]\n", 2, "poses.a.1", "'2' is out of range: must be in [-1, 1] rad"),
    ],
)
def test_a_number_out_of_its_range_is_one_error_at_its_line(text, line, key, problem) -> None:
    with pytest.raises(ConfigError) as e:
        load_text(Ranged, text, source="r.yaml")
    assert (e.value.line, e.value.key) == (line, key) and problem in e.value.problem


def test_ranges_are_checked_on_overrides_and_found_through_optionals() -> None:
    loaded = load_text(Ranged, "reach: [1, 2, 3]\nposes: {a: [0.5]}\n", source="r.yaml")
    assert str(range_of(type_at(loaded.value, ["reach", "0"]))) == "[-10, 10] m"  # through `| None`
    assert str(range_of(type_at(loaded.value, ["poses", "a", "0"]))) == "[-1, 1] rad"
    for assignment, key in [("reach.2=20", "reach.2"), ("poses.a.0=-3", "poses.a.0"), ("period=nan", "period"),
                            ("where=[0, 0, 1.0e+9]", "where.2"), ("count=11", "count")]:
        with pytest.raises(ConfigError) as e:
            apply_override(loaded, assignment)
        assert e.value.key == key and ("out of range" in e.value.problem or "finite" in e.value.problem)
    apply_override(loaded, "reach.2=-10")
    assert loaded.value.reach == (1.0, 2.0, -10.0)
    again = load_text(Ranged, dump_yaml(loaded.value)).value  # Annotated types dump and load back
    assert again == loaded.value and to_data(again)["poses"] == {"a": [0.5]}


def test_range_text() -> None:
    assert str(Range(0.0, 1.0, lo_open=True, unit="s")) == "(0, 1] s"
    assert str(Range(0, 2**32 - 1)) == "[0, 4294967295]"
    assert str(Range(lo=0.0, hi_open=True)) == "[0, inf)"
    assert Range(0.0, 1.0, hi_open=True).admits(0.0) and not Range(0.0, 1.0, hi_open=True).admits(1.0)


LAUGHS = "[" + ", ".join(
    [f"&a0 [{', '.join(['1'] * 9)}]"] + [f"&a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 9)]
) + "]"


@pytest.mark.parametrize(
    "value, problem",
    [(LAUGHS, "expands to more than"), ("[" * 5000 + "]" * 5000, "nested deeper than")],
    ids=["billion laughs", "deep nesting"],
)
def test_a_bomb_is_refused_in_a_file_and_in_an_override(value, problem) -> None:
    with pytest.raises(ConfigError) as e:
        load_text(Ranged, f"free: 1\nposes: {{a: {value}}}\n", source="r.yaml")
    assert e.value.line == 2 and problem in e.value.problem
    loaded = load_text(Ranged, "free: 1\n")
    with pytest.raises(ConfigError) as e:
        apply_override(loaded, f"poses={value}")
    assert e.value.source == "--set" and e.value.key == "poses" and problem in e.value.problem


def test_a_file_too_long_is_refused_without_reading_it_whole(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(typed_yaml, "MAX_FILE_CHARS", 100)
    path = tmp_path / "long.yaml"
    path.write_text("free: 1\n" + "# comment\n" * 20)
    with pytest.raises(ConfigError, match="file too long: more than 100 characters"):
        load_file(Ranged, path)


def test_a_set_value_is_read_as_the_file_reads_it():
    """The audit's: --set read values as YAML 1.1 (PyYAML), so 'off' and 'yes' were booleans on the command line only
    ('expected a string, got false', where the same word is accepted in the file)."""
    from cellsim.scenario import load_scenario

    from conftest import ROOT

    tending = ROOT / "scenarios" / "machine_tending.yaml"
    sc = load_scenario(tending, ["robot.activities=[idle, fetching, loading, off]"]).scenario
    assert sc.entities["robot"].activities[-1] == "off"
    sc = load_scenario(tending, ["robot.activities=\n- idle\n- fetching\n- loading\n- yes"]).scenario  # (a block)
    assert sc.entities["robot"].activities == ["idle", "fetching", "loading", "yes"]


def test_a_file_not_utf8_is_named_at_its_line_and_a_base_that_is_a_folder_says_so(tmp_path):
    """The audit's: a Latin-1 file gave a byte offset in a decoding buffer, no line; a base naming a folder said
    'file not found'."""
    from cellsim.scenario import load_scenario

    latin = tmp_path / "latin.yaml"
    latin.write_bytes(b"name: x\n# " + b"a" * 20000 + b"\n\ndescription: caf\xe9\n")
    with pytest.raises(ConfigError) as e:
        load_scenario(latin)
    assert (e.value.line, e.value.problem) == (4, "not UTF-8 text: byte 0xe9 cannot be read (save the file as UTF-8)")
    (tmp_path / "folder.yaml").mkdir()
    child = tmp_path / "child.yaml"
    child.write_text("base: folder.yaml\nname: x\n")
    with pytest.raises(ConfigError) as e:
        load_scenario(child)
    assert e.value.key == "base" and "folder.yaml is a folder, not a base file" in e.value.problem


@dataclass
class Aim:
    at: tuple[float, float, float]


@dataclass
class Poses:
    poses: dict[str, list[float] | Aim] = field(default_factory=dict)
    either: int | str = 0


@pytest.mark.parametrize(
    "text, line, key, problem",
    [
        # a list is meant as the list member, a mapping as the dataclass: the error is inside it
        ("poses:\n  home:\n    - 1\n    - x\n", 4, "poses.home.1", "expected a number, got 'x'"),
        ("poses:\n  home: {at: [1, 2]}\n", 2, "poses.home.at", "expected a list of 3 items, got 2"),
        ("poses:\n  home: {aim: [1, 2, 3]}\n", 2, "poses.home.aim", "unknown key 'aim' (expected one of: at)"),
        # a value of no member's shape, or of several members' shape, is named at its own key
        ("poses:\n  home: 7\n", 2, "poses.home", "expected a list or a mapping, got '7'"),
        ("either: [1]\n", 1, "either", "expected an integer or a string, got a list"),
    ],
)
def test_a_bad_value_inside_a_union_member_is_named_where_it_is(text, line, key, problem) -> None:
    with pytest.raises(ConfigError) as e:
        load_text(Poses, text, source="p.yaml")
    assert (e.value.line, e.value.key) == (line, key) and problem in e.value.problem, str(e.value)
