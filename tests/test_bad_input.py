"""Bad input never crashes: one line naming the file, line and key, exit 2, nothing written.

Run as a user would, as processes with a deadline: a hang or a segfault fails the test.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import WELDING_CELL

LAUGHS = "\n".join(
    ["name: lol", "layout: {}", "entities: {}", "campaign:", "  samplers:", "    x:", "      kind: choice", "      values:",
     '        - &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    + [f"        - &{b} [{','.join(['*' + a] * 9)}]" for a, b in zip("abcdefgh", "bcdefghi")]
) + "\n"

BOMBS = {
    "100 000 levels of nesting": ("name: x\nentities: " + "[" * 100_000 + "]" * 100_000 + "\n", "nested deeper than 100 levels"),
    "billion laughs": (LAUGHS, "expands to more than"),
    "recursive alias": ("name: &a [*a]\n", "recursive YAML alias"),
}


def cellsim(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cellsim.cli", *args], capture_output=True, text=True, timeout=timeout)


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err[:2000]
    return lines[0]


@pytest.mark.parametrize("bomb", list(BOMBS))
def test_yaml_bombs_are_one_line_in_bounded_time(tmp_path, bomb):
    text, expected = BOMBS[bomb]
    path = tmp_path / "bomb.yaml"
    path.write_text(text)
    out = tmp_path / "run"
    done = cellsim("simulate", str(path), "--out", str(out), timeout=60)  # a hang fails at the timeout
    assert done.returncode == 2, done.stderr[-2000:]
    assert expected in one_line(done.stderr) and str(path) in done.stderr
    assert not out.exists()


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="needs /dev/zero")
def test_an_endless_file_is_one_line_in_bounded_memory(tmp_path):
    out = tmp_path / "run"
    done = cellsim("simulate", "/dev/zero", "--out", str(out), timeout=60)
    assert done.returncode == 2
    assert one_line(done.stderr) == "cellsim: error: /dev/zero: file too long: more than 10,000,000 characters"
    assert not out.exists()


SET_BOMBS = {
    "billion laughs": ("[" + ", ".join(['&a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
                                       + [f"&{b} [{','.join(['*' + a] * 9)}]" for a, b in zip("abcdefgh", "bcdefghi")]) + "]",
                       "malformed value: expands to more than"),
    "100 000 levels of nesting": ("[" * 100_000 + "]" * 100_000, "malformed value: nested deeper than 100 levels"),
}


@pytest.mark.parametrize("bomb", list(SET_BOMBS))
def test_a_bomb_in_a_set_value_is_one_error(bomb):
    from cellsim.config.typed_yaml import ConfigError
    from cellsim.scenario import load_scenario

    value, expected = SET_BOMBS[bomb]
    with pytest.raises(ConfigError) as e:
        load_scenario(WELDING_CELL, [f"configuration_points.operator_waits.paths={value}"])
    assert (e.value.source, e.value.key) == ("--set", "configuration_points.operator_waits.paths")
    assert expected in e.value.problem


def test_sigint_during_start_up_is_one_line_and_130(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cellsim.cli", "simulate", str(WELDING_CELL), "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        # interrupt while it is still starting up: once it is loading Drake (mapped into the
        # process), before it has built anything
        deadline = time.monotonic() + 60
        maps = Path(f"/proc/{proc.pid}/maps")
        while "pydrake" not in maps.read_text():
            assert time.monotonic() < deadline and proc.poll() is None, "never started loading Drake"
            time.sleep(0.001)  # polling another process's memory map: there is no event to wait on
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert one_line(err) == "cellsim: interrupted"
    assert not out.exists()


# --------------------------------------------------------------------------- numbers

def _numbers_without_range(cls, prefix="", seen=None) -> list[str]:
    """Every float or int reachable from a dataclass schema that carries no Range."""
    import dataclasses
    import typing

    from cellsim.config.typed_yaml import range_of

    seen = set() if seen is None else seen
    if cls in seen:
        return []
    seen.add(cls)
    missing = []

    def walk(tp, where, ranged):
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if origin is typing.Annotated:
            return walk(args[0], where, ranged or range_of(tp) is not None)
        if tp in (float, int):
            if not ranged:
                missing.append(where)
        elif isinstance(tp, type) and dataclasses.is_dataclass(tp):
            missing.extend(_numbers_without_range(tp, where + ".", seen))
        elif hasattr(tp, "__kind_names__"):
            from cellsim import registry

            for name in tp.__kind_names__():
                missing.extend(_numbers_without_range(registry.get(name).config, f"{where}<{name}>.", seen))
        else:
            for arg in args:
                if arg is not Ellipsis and arg is not type(None):
                    walk(arg, where, ranged)

    hints = typing.get_type_hints(cls, include_extras=True)
    for f in dataclasses.fields(cls):
        if f.init:
            walk(hints[f.name], prefix + f.name, False)
    return missing


EXEMPT = {
    # a coverage bin's edges: any finite numbers, in the variable's unit, increasing
    "validation.bins.edges",
    # a sampler's numbers: checked against the ranges of the fields they are drawn for
    "campaign.samplers.low", "campaign.samplers.high", "campaign.samplers.values",
    "campaign.samplers.total", "campaign.samplers.minimum",
}


def test_every_number_of_the_scenario_schema_has_a_valid_range():
    from cellsim.kinds.safety_controller.risk_model import RiskModelFile
    from cellsim.scenario import Scenario

    assert set(_numbers_without_range(Scenario)) <= EXEMPT and _numbers_without_range(RiskModelFile) == []


@pytest.mark.parametrize(
    "override, expected",
    [
        ("campaign.samplers.operator_waits.total=1.0e+6", "campaign.samplers.operator_waits.total: draws 1e+06, outside what"),
    ],
)
def test_a_sampler_that_would_draw_out_of_range_is_refused_at_load_time(override, expected):
    from cellsim.config.typed_yaml import ConfigError
    from cellsim.scenario import load_scenario

    import re

    with pytest.raises(ConfigError, match=re.escape(expected)):
        load_scenario(WELDING_CELL, [override])


def test_a_choice_a_field_cannot_take_is_refused_at_its_line_before_any_run(tmp_path, capsys):
    """An audit found a choice of 'shadw' for a twin mode passing `scenario check`, then failing the campaign's
    runs that drew it, the bound stated over both values: each value is now set on the scenario at load time."""
    from cellsim.cli import main

    scenario = tmp_path / "choice.yaml"
    scenario.write_text(f"base: {WELDING_CELL}\nname: choice\nconfiguration_points:\n"
                        "  barrier_mode: {paths: [light_barrier.twin.mode]}\ncampaign:\n  samplers:\n"
                        "    barrier_mode: {kind: choice, values: [model, shadw]}\n")
    assert main(["scenario", "check", str(scenario)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{scenario}:7:" in err and "values.1" in err and "shadw" in err
    scenario.write_text(scenario.read_text().replace("shadw", "shadow"))
    assert main(["scenario", "check", str(scenario)]) == 0


BAD_NUMBERS = {
    # category: (override path, bad values)
    "period": ("robot.period", ["nan", ".inf", "0", "-0.02", "1e9", "0.003"]),
    "time step": ("time_step", ["nan", "0", "-1", "1.0e-9", "5"]),
    "duration": ("duration", ["nan", ".inf", "0", "-3", "1.0e+9"]),
    "speed": ("operator.walking_speed", ["nan", "-.inf", "0", "-1", "1000"]),
    "wait": ("operator.waypoints.cell.wait", ["nan", ".inf", "-1", "1.0e+9"]),
    "threshold": ("range_detector.near_below", ["nan", "0", "-2", "1000"]),
    "size": ("light_barrier.size", ["[0, 1, 1]", "[-1, 1, 1]", "[1, .nan, 1]", "[1000, 1, 1]"]),
    "radius": ("operator.body_radius", ["0", "-0.2", "nan", "50"]),
    "colour": ("layout.fixtures.shared_table.color", ["[2, 0, 0, 1]", "[0, -1, 0, 1]", "[0, 0, .nan, 1]"]),
    "seed": ("seed", ["-1", "99999999999999999999"]),
    "position": ("range_detector.position", ["[.inf, 0, 0]", "[1.0e+9, 0, 0]", "[0, .nan, 0]"]),
    "joint angle": ("robot.named_poses.home.0", ["nan", "100", "-7"]),
    "stale after": ("robot.twin.stale_after", ["0", "-1", ".inf"]),
    "braking time": ("robot.braking_time", ["0", "nan", "1000"]),
    "noise": ("range_detector.noise_std", ["-0.1", "nan", "100"]),
}


@pytest.mark.parametrize(
    "path, value", [(path, v) for path, values in BAD_NUMBERS.values() for v in values],
    ids=[f"{cat}={v}" for cat, (_, values) in BAD_NUMBERS.items() for v in values],
)
def test_a_bad_number_is_refused_at_load_time_naming_it(path, value):
    from cellsim.config.typed_yaml import ConfigError
    from cellsim.scenario import load_scenario

    with pytest.raises(ConfigError) as e:
        load_scenario(WELDING_CELL, [f"{path}={value}"])
    text = str(e.value)
    assert "\n" not in text
    assert path.split(".")[-1] in text or path.split(".")[-2] in text, text


def test_a_bad_number_in_the_file_names_file_line_and_key_and_writes_nothing(tmp_path):
    import shutil

    folder = tmp_path / "scenario"
    shutil.copytree(WELDING_CELL.parent, folder)
    scenario = folder / "welding_cell.yaml"
    text = scenario.read_text()
    assert "    close_below: 1.0\n" in text
    scenario.write_text(text.replace("    close_below: 1.0\n", "    close_below: .nan\n"))
    line = next(i for i, l in enumerate(scenario.read_text().splitlines(), 1) if "close_below: .nan" in l)
    out = tmp_path / "run"
    done = cellsim("simulate", str(scenario), "--out", str(out))
    assert done.returncode == 2
    assert one_line(done.stderr) == (
        f"cellsim: error: {scenario}:{line}: entities.range_detector.close_below: expected a finite number, got '.nan'"
    )
    assert not out.exists()


@pytest.mark.parametrize(
    "args, expected",
    [
        (["--duration", "1e9"], "--duration: 1e+09 is out of range: must be in (0, 86400] s"),
        (["--duration", "nan"], "--duration: nan is out of range"),
        (["--duration", "0"], "--duration: 0 is out of range"),
        (["--seed", "-1"], "--seed: -1 is out of range"),
        (["--set", "time_step=0.0001", "--duration", "86400"],
         "864,000,000 plant steps, more than the 50,000,000 a run may take: at most 5,000 s at this time_step, "
         "or a time_step of at least 0.00173 s"),
        # one step over the limit is said as such, not rounded to the limit itself
        (["--set", "time_step=0.001", "--duration", "50000.001"], "50,000,001 plant steps, more than the 50,000,000"),
        (["--set", "robot.period=0.002", "--set", "operator.period=0.002", "--set", "safety_controller.period=0.002",
          "--duration", "86400"], "module updates (robot every 0.002 s, operator every 0.002 s, "
                                  "safety_controller every 0.002 s, ...), more than the 100,000,000 a run may take"),
    ],
)
def test_absurd_runs_are_refused_with_a_reason(tmp_path, args, expected):
    out = tmp_path / "run"
    done = cellsim("simulate", str(WELDING_CELL), "--out", str(out), *args)
    assert done.returncode == 2 and expected in one_line(done.stderr)
    assert not out.exists()


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("short") / "run"
    assert cellsim("simulate", str(WELDING_CELL), "--out", str(out), "--duration", "3", "--quiet").returncode in (0, 1)
    return out


@pytest.mark.parametrize("command", ["export", "export-trace"])
@pytest.mark.parametrize("target, expected", [("a_folder", "is a folder; name a file to write"),
                                              ("missing/x.json", "no such folder to write into")])
def test_writing_to_a_folder_or_into_nothing_is_one_line_and_leaves_no_tmp(tmp_path, short_run, command, target, expected):
    (tmp_path / "a_folder").mkdir()
    destination = tmp_path / target
    args = (["scenario", "export", str(WELDING_CELL), "--out", str(destination)] if command == "export"
            else ["check", str(short_run), "--export-trace", str(destination)])
    done = cellsim(*args)
    assert done.returncode == 2 and expected in one_line(done.stderr)
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a_folder"]


URDF = (Path(__file__).resolve().parents[1] / "scenarios" / "models" / "ur10.urdf").read_text()
BAD_MODELS = {
    "empty file": ("", "entities.robot.model: not a robot model Drake can read"),
    "not XML": ("this is not a robot\n", "entities.robot.model: not a robot model Drake can read"),
    "XML, not a model": ("<notes><note>hi</note></notes>\n", "entities.robot.model: not a robot model Drake can read"),
    "no base_link": (URDF.replace('"base_link"', '"pedestal_link"'), "has no link named 'base_link'"),
    "no tool frame": (URDF.replace('name="tcp"', 'name="tip"').replace('child link="tcp"', 'child link="tip"'), "entities.robot.tool_frame: models/ur10.urdf has no frame named 'tcp'"),
}


@pytest.mark.parametrize("case", list(BAD_MODELS))
def test_a_bad_robot_model_is_one_line_not_a_drake_traceback(tmp_path, case):
    import shutil

    text, expected = BAD_MODELS[case]
    if case == "no base_link":
        assert '"base_link"' in URDF
    if case == "no tool frame":
        assert 'name="tcp"' in URDF
    folder = tmp_path / "scenario"
    shutil.copytree(WELDING_CELL.parent, folder)
    (folder / "models" / "ur10.urdf").write_text(text)
    out = tmp_path / "run"
    done = cellsim("simulate", str(folder / "welding_cell.yaml"), "--out", str(out))
    assert done.returncode == 2
    line = one_line(done.stderr)
    assert expected in line and str(folder / "welding_cell.yaml") in line
    assert not out.exists()


VALIDATION = WELDING_CELL.parent / "welding_cell_validation.yaml"


@pytest.mark.parametrize(
    "edit, key, expected",
    [
        (("variables: [rloc, rngDet]", "variables: [rloc, rngdet]"), "coverage.rloc x rngDet.variables.1", "did you mean 'rngDet'?"),
        (("  safmod: [normal, ssmon, pflim, stopped]", "  safmod: [normal, ssmon, plfim, stopped]"), "domains.safmod.2", "'plfim'"),
        (("  HS: [inact, act, mit, res]", "  HSS: [inact, act, mit, res]"), "domains.HSS", "did you mean 'HS'?"),
        (("    use_case: U1", "    use_case: U9"), "coverage.U1 welder x range.use_case", "no use case named 'U9'"),
        (("  sep: {edges: [0.5, 1.0, 2.0]}", "  sepp: {edges: [0.5, 1.0, 2.0]}"), "bins.sepp", "did you mean 'sep'?"),
    ],
)
def test_coverage_errors_point_at_the_entry_at_fault(tmp_path, edit, key, expected):
    import shutil

    from cellsim.config.typed_yaml import ConfigError
    from cellsim.validation.check import scenario_safety_case
    from cellsim.scenario import load_scenario

    folder = tmp_path / "scenario"
    shutil.copytree(WELDING_CELL.parent, folder)
    validation = folder / VALIDATION.name
    text = validation.read_text()
    assert edit[0] in text
    validation.write_text(text.replace(*edit, 1))
    with pytest.raises(ConfigError) as e:
        scenario_safety_case(load_scenario(folder / "welding_cell.yaml"))
    line = next(i for i, l in enumerate(validation.read_text().splitlines(), 1) if edit[1].strip() in l)
    assert (e.value.source, e.value.key) == (str(validation), key)
    assert expected in e.value.problem
    if key.count(".") <= 2 or "use_case" in key:  # the entry's own line (list items are on their list's line)
        assert e.value.line == line


@pytest.mark.parametrize(
    "edit, expected",
    [
        (("      rngDet: range_detector.range\n", "      rngDet: range_detector.rang\n"),
         "behaviours.safety_controller.monitors.rngDet: no channel 'range_detector.rang'; did you mean 'range_detector.range'?"),
        (("[robot.safety_mode_request, welder.safety_mode_request]", "[robot.safety_mode_requst, welder.safety_mode_request]"),
         "no command input 'robot.safety_mode_requst'; did you mean 'robot.safety_mode_request'?"),
    ],
)
def test_a_misspelt_channel_gets_a_did_you_mean_not_every_channel(tmp_path, edit, expected):
    import shutil

    folder = tmp_path / "scenario"
    shutil.copytree(WELDING_CELL.parent, folder)
    scenario = folder / "welding_cell.yaml"
    text = scenario.read_text()
    assert edit[0] in text
    scenario.write_text(text.replace(*edit, 1))
    done = cellsim("scenario", "check", str(scenario))
    assert done.returncode == 2
    line = one_line(done.stderr)
    assert expected in line and "robot.location" not in line  # not a list of every channel


def test_a_coverage_criterion_too_large_to_report_is_refused_at_its_line(tmp_path):
    import shutil

    from cellsim.config.typed_yaml import ConfigError
    from cellsim.scenario import load_scenario
    from cellsim.validation.check import scenario_safety_case

    folder = tmp_path / "scenario"
    shutil.copytree(WELDING_CELL.parent, folder)
    validation = folder / VALIDATION.name
    text = validation.read_text()
    bins = "  sep: {edges: [0.5, 1.0, 2.0]}"
    assert bins in text
    edges = ", ".join(f"{i / 1000:g}" for i in range(1, 100_001))  # 100 001 bins
    validation.write_text(text.replace(bins, f"  sep: {{edges: [{edges}]}}"))
    with pytest.raises(ConfigError) as e:
        scenario_safety_case(load_scenario(folder / "welding_cell.yaml"))
    line = next(i for i, l in enumerate(text.splitlines(), 1) if l.startswith("  separation:"))
    assert (e.value.source, e.value.line, e.value.key) == (str(validation), line, "coverage.separation")
    assert "has 100,001 situations (100001 sep), more than the 100,000 a criterion may have" in e.value.problem


# a model Drake reads but the cell cannot use: refused when the cell is built (in-process: no simulation)
MODELS_THE_CELL_REFUSES = {
    "a massless link": (URDF.replace('<mass value="4.0"/>', '<mass value="0"/>', 1), "entities.robot.model",
                        "not a robot model Drake can read: "),
    "joints that cannot move": (URDF.replace('velocity="2.16"', 'velocity="0"'), "entities.robot.model",
                                "joint 'shoulder_pan_joint' of models/ur10.urdf has velocity limit 0: it could never move"),
    "a named pose beyond the joint limits": (
        URDF.replace('lower="-6.283185307179586" upper="6.283185307179586" effort="330" velocity="2.16"',
                     'lower="-1.0" upper="1.0" effort="330" velocity="2.16"', 1),
        "entities.robot.named_poses.home.0",
        "1.3576 rad is outside the limits of joint 'shoulder_pan_joint' in models/ur10.urdf: [-1, 1] rad"),
}


@pytest.mark.parametrize("case", list(MODELS_THE_CELL_REFUSES))
def test_a_robot_model_the_cell_cannot_use_is_refused_at_build(tmp_path, case):
    import shutil

    from cellsim.config.typed_yaml import ConfigError
    from cellsim.scenario import load_scenario
    from cellsim.validation.check import scenario_safety_case

    text, key, expected = MODELS_THE_CELL_REFUSES[case]
    assert text != URDF
    folder = tmp_path / "scenario"
    shutil.copytree(WELDING_CELL.parent, folder)
    (folder / "models" / "ur10.urdf").write_text(text)
    with pytest.raises(ConfigError) as e:
        scenario_safety_case(load_scenario(folder / "welding_cell.yaml"))
    assert (e.value.source, e.value.key) == (str(folder / "welding_cell.yaml"), key)
    assert expected in e.value.problem and "\n" not in str(e.value)


# --------------------------------------------------------------------------- the documented ranges

def test_the_schema_reference_is_current():
    from cellsim.kinds_doc import SCHEMA_DOC, schema_markdown

    written = (Path(__file__).resolve().parents[1] / SCHEMA_DOC).read_text()
    assert written == schema_markdown(), f"{SCHEMA_DOC} is out of date: python -m cellsim.kinds_doc > {SCHEMA_DOC}"


def _ranged_fields(cls, seen=None) -> list[tuple[str, str]]:
    """(field name, its range) of every field with a Range reachable from a dataclass."""
    import dataclasses
    import typing

    from cellsim.config.typed_yaml import range_of

    seen = set() if seen is None else seen
    if cls in seen:
        return []
    seen.add(cls)
    found = []

    def walk(name, tp):
        ranged = range_of(tp)
        if ranged is not None:
            found.append((name, str(ranged)))
        for arg in typing.get_args(tp):
            if isinstance(arg, type) and dataclasses.is_dataclass(arg):
                found.extend(_ranged_fields(arg, seen))
            elif arg is not Ellipsis and not isinstance(arg, (str, int, float)):
                walk(name, arg)

    hints = typing.get_type_hints(cls, include_extras=True)
    for f in dataclasses.fields(cls):
        if isinstance(hints[f.name], type) and dataclasses.is_dataclass(hints[f.name]):
            found.extend(_ranged_fields(hints[f.name], seen))
        else:
            walk(f.name, hints[f.name])
    return found


def test_the_schema_reference_gives_every_numbers_range():
    import re

    from cellsim import registry
    from cellsim.kinds.safety_controller.risk_model import RiskModelFile
    from cellsim.kinds_doc import SCHEMA_DOC
    from cellsim.scenario import Scenario

    text = (Path(__file__).resolve().parents[1] / SCHEMA_DOC).read_text()
    rows = [[c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]] for line in text.splitlines() if line.startswith("| `")]
    documented = {(key.strip("`").rsplit(".", 1)[-1], valid) for key, _type, _default, valid, _doc in rows}
    schemas = [Scenario, RiskModelFile] + [registry.get(n).config for n in registry.kind_names()
                                           if registry.get(n).config.__module__.startswith("cellsim.")]
    wanted = {pair for cls in schemas for pair in _ranged_fields(cls)}
    assert len(wanted) > 25 and wanted <= documented, sorted(wanted - documented)


@pytest.mark.parametrize(
    "override, expected",
    [
        ("layout.robot_elsewhere=unknown", "'unknown' is what a shadowed robot reports"),
        ("robot.activities=[idle, idle]", "activities must be distinct identifiers"),
        ("process_controller.steps.1.name=fetch", "step names must differ"),
    ],
)
def test_declared_names_that_would_collide_are_refused_at_load(override, expected):
    from cellsim.config.typed_yaml import ConfigError
    from cellsim.scenario import load_scenario

    with pytest.raises(ConfigError, match=expected):
        load_scenario(WELDING_CELL, [override])


def test_a_pose_named_moving_is_refused(tmp_path):
    from cellsim.config.typed_yaml import ConfigError
    from cellsim.scenario import load_scenario

    path = tmp_path / "moving.yaml"
    path.write_text(f"base: {WELDING_CELL}\nentities:\n  robot:\n    named_poses:\n      moving: [0, 0, 0, 0, 0, 0]\n")
    with pytest.raises(ConfigError, match="'moving' is what reached_pose reads") as e:
        load_scenario(path)
    assert e.value.line == 5


def test_any_identifier_is_a_value_even_the_enum_machinerys_own_words(tmp_path):
    """Names such as mro or _x_ once crashed the enum a cell's vocabulary becomes."""
    from cellsim.scenario import load_scenario
    from cellsim.diagrams.cell import build_cell

    path = tmp_path / "odd.yaml"
    path.write_text(
        f"base: {WELDING_CELL}\nlayout:\n  robot_elsewhere: mro\n"
        "entities:\n  robot:\n    activities: [_x_, name, __x__]\n"
        "behaviours: !replace {}\nvalidation: !replace {}\n"
    )
    robot = build_cell(load_scenario(path), seed=0, duration=1.0, record=False).modules["robot"]
    assert [m.value for m in robot.locations][-2:] == ["mro", "unknown"]
    assert [m.value for m in robot.activity_type] == ["_x_", "name", "__x__", "unknown"]
