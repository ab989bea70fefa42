"""The public Python API (issue 37): every task from ``import cellsim`` alone, no cellsim submodule named.

Load a scenario with overrides, or build one in code; build its diagram and put a system of one's own into it;
simulate and read the run back as arrays, a DataFrame, verdicts and explanations; campaigns, searches and
verification with the same results the CLI writes. The CLI's commands are users of this API.
"""

from __future__ import annotations

import ast
import json
import re
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.framework import BasicVector, LeafSystem

import cellsim

ROOT = Path(__file__).resolve().parents[1]
WELDING = ROOT / "scenarios" / "welding_cell.yaml"
sys.path.insert(0, str(ROOT / "diagrams"))


def _rows(blackbox: Path) -> list[tuple]:
    """A black box's messages, read with sqlite3 (not cellsim's reader)."""
    db = sqlite3.connect(blackbox)
    try:
        return db.execute("SELECT t, channel, source, payload FROM messages ORDER BY rowid").fetchall()
    finally:
        db.close()


def test_the_public_names_are_documented_and_need_no_submodule():
    assert set(cellsim.__all__) == set(dir(cellsim)) - {"__version__"}
    for name in cellsim.__all__:
        value = getattr(cellsim, name)
        assert value is not None
        if callable(value) and not isinstance(value, type(cellsim)):
            assert (value.__doc__ or "").strip(), f"cellsim.{name} has no docstring"
    with pytest.raises(AttributeError):
        cellsim.no_such_thing  # noqa: B018



def test_a_scenario_loads_with_overrides_and_a_bad_one_is_one_error_naming_file_line_and_key(tmp_path):
    sf = cellsim.load_scenario(WELDING, ["seed=7", "operator.walking_speed=1.0"])
    assert sf.scenario.seed == 7 and sf.scenario.entities["operator"].walking_speed == 1.0
    with pytest.raises(cellsim.ConfigError) as e:
        cellsim.load_scenario(WELDING, ["range_detector.near_below=-3"])
    assert "range_detector.near_below" in str(e.value) and "\n" not in str(e.value)
    bad = tmp_path / "bad.yaml"
    bad.write_text(WELDING.read_text().replace("walking_speed: 1.2", "walking_speed: fast"))
    with pytest.raises(cellsim.ConfigError) as e:
        cellsim.load_scenario(bad)
    assert e.value.source == str(bad) and e.value.line is not None and "walking_speed" in e.value.key


def test_a_module_built_in_code_is_checked_as_a_files_and_names_the_field():
    curtain = cellsim.module("light_barrier", center=(-1.37, 0.0, 1.25), size=(0.02, 0.9, 0.7))
    assert isinstance(curtain, cellsim.kind_config("light_barrier")) and curtain.size == (0.02, 0.9, 0.7)
    with pytest.raises(cellsim.ConfigError) as e:
        cellsim.module("light_barrier", center=(0, 0, 1), size=(0.02, -0.9, 0.7))
    assert "size" in e.value.key
    with pytest.raises(KeyError, match="no module kind 'lidar'"):
        cellsim.kind_config("lidar")


def test_the_welding_cell_in_code_and_from_yaml_give_the_same_black_box(tmp_path):
    from welding_cell import SCENARIOS, welding_cell

    in_code = cellsim.scenario_in_code(welding_cell(), base_dir=SCENARIOS)
    assert in_code.built_in_code and "built in Python" in in_code.source
    a = cellsim.simulate(in_code, tmp_path / "code", seed=3, duration=12.0)
    b = cellsim.simulate(cellsim.load_scenario(WELDING), tmp_path / "yaml", seed=3, duration=12.0)
    rows = _rows(a.out / "blackbox.sqlite")
    assert len(rows) > 500 and rows == _rows(b.out / "blackbox.sqlite")
    assert a.verdicts == b.verdicts
    # the run re-runs alone: its folder holds the resolved scenario, which loads
    assert cellsim.load_scenario(a.out / "scenario.yaml").scenario.name == "welding_cell"


def test_a_bad_scenario_built_in_code_names_its_key():
    from welding_cell import SCENARIOS, welding_cell

    scenario = welding_cell()
    scenario.entities["robot"].initial_pose = "nowhere"
    with pytest.raises(cellsim.ConfigError) as e:
        cellsim.scenario_in_code(scenario, base_dir=SCENARIOS)
    assert "welding_cell (built in Python)" in str(e.value) and "initial_pose" in str(e.value)


def test_a_run_reads_back_as_arrays_a_dataframe_verdicts_and_explanations(tmp_path):
    ticks = []
    run = cellsim.simulate(cellsim.load_scenario(WELDING), tmp_path / "run", seed=0, duration=6.0,
                           progress=lambda t, total: ticks.append((t, total)))
    assert ticks == [(float(k), 6.0) for k in range(1, 7)]
    assert run.summary.status == "completed" and run.summary.sim_time == pytest.approx(6.0)
    series = run.series("ground_truth.separation", "robot.safety_mode")
    separation = series["ground_truth.separation"]
    assert isinstance(separation.times, np.ndarray) and separation.times[0] == 0.0
    rows = [r for r in _rows(run.out / "blackbox.sqlite") if r[1] == "ground_truth.separation"]
    assert [json.loads(r[3])["value"] for r in rows] == pytest.approx(separation.values)
    frame = run.dataframe(["ground_truth.separation", "robot.safety_mode"])
    assert list(frame.columns) == ["ground_truth.separation", "robot.safety_mode"] and frame.index.name == "t"
    # each value holds from its message on: read at any instant, the frame says what a reader saw then
    t = float(separation.times[7]) + 0.05
    held = frame["ground_truth.separation"][frame.index <= t].iloc[-1]
    assert held == pytest.approx(separation.value_at(t))
    sampled = run.dataframe(["ground_truth.separation"], period=0.5)
    assert list(sampled.index) == pytest.approx([0.5 * k for k in range(13)])
    assert sampled["ground_truth.separation"].iloc[4] == pytest.approx(separation.value_at(2.0))
    vectors = run.dataframe(["robot.joint_positions"])
    assert [c for c in vectors.columns] == [f"robot.joint_positions[{i}]" for i in range(6)]
    # the verdicts, and why one does not hold
    assert run.verdicts["NoHarm"] == "holds" and run.verdicts["Final:Tbl"] == "violated"
    why = run.explain("Final:Tbl")
    assert why.startswith("violated at") and "otab" in why
    assert run.explain("NoHarm") is None
    assert cellsim.check(run).result.verdicts.keys() == run.checked.result.verdicts.keys()
    again = cellsim.Run.open(run.out)
    assert again.summary.status == "completed" and again.verdicts == run.verdicts


class NaiveController(LeafSystem):
    """A hand-written safety controller: it stops the arm while the light curtain is broken and otherwise lets it
    run at full speed, ignoring the range detector (the point: a condition catches it)."""

    def __init__(self, broken: float, normal: float, stopped: float, heed_scanner: float | None = None):
        super().__init__()
        self.normal, self.stopped, self.heed = normal, stopped, heed_scanner
        self.curtain = self.DeclareVectorInputPort("curtain", 1)
        self.scanner = self.DeclareVectorInputPort("scanner", 1)
        self.broken = broken
        self.DeclareVectorOutputPort("mode", 1, self._mode)

    def _mode(self, context, output: BasicVector) -> None:
        stop = self.curtain.Eval(context)[0] == self.broken
        if self.heed is not None and self.scanner.Eval(context)[0] == self.heed:
            stop = True
        output.SetAtIndex(0, self.stopped if stop else self.normal)


def _with_controller(tmp_path, name: str, heed_scanner: bool):
    """The welding cell with its risk-model engine replaced by a hand-written controller, judged by a condition
    written here."""
    sf = cellsim.load_scenario(WELDING)
    del sf.scenario.behaviours["safety_controller"]
    sf.scenario.validation = cellsim.Validation(conditions={
        "StopsWhenClose": "G(range_detector.range == close -> F[0, 0.5s] robot.safety_mode == stopped)"})
    wired = {}

    def extend(cell):
        controller = cell.builder.AddSystem(NaiveController(
            cell.code_of("light_barrier.broken", True), cell.code_of("robot.safety_mode", "normal"),
            cell.code_of("robot.safety_mode", "stopped"),
            cell.code_of("range_detector.range", "close") if heed_scanner else None))
        cell.builder.Connect(cell.channel("light_barrier.broken"), controller.GetInputPort("curtain"))
        cell.builder.Connect(cell.channel("range_detector.range"), controller.GetInputPort("scanner"))
        cell.builder.Connect(controller.GetOutputPort("mode"), cell.module_input("robot.safety_mode_request"))
        wired["controller"] = controller

    built = cellsim.build(sf, extend=extend)
    assert wired["controller"] in built.diagram.GetSystems() and "safety_controller" not in built.modules
    assert built.diagram.HasOutputPort("range_detector.range")  # the named ports, exported as they are named
    return cellsim.simulate(sf, tmp_path / name, seed=0, duration=24.0, extend=extend)


def test_a_hand_written_controller_replaces_the_risk_model_engine_and_check_judges_it(tmp_path):
    naive = _with_controller(tmp_path, "naive", heed_scanner=False)
    assert naive.verdicts["StopsWhenClose"] == "violated" and naive.finding
    assert "range_detector.range" in naive.explain("StopsWhenClose") or "close" in naive.explain("StopsWhenClose")
    careful = _with_controller(tmp_path, "careful", heed_scanner=True)
    assert careful.verdicts["StopsWhenClose"] == "holds"
    # the arm took the modes each controller asked for: the naive one stops only for the curtain, the careful one
    # also while the scanner reads close with the curtain clear
    channels = ["robot.safety_mode", "light_barrier.broken", "range_detector.range"]
    for run, stops_for_scanner in ((naive, False), (careful, True)):
        frame = run.dataframe(channels)
        mode = frame["robot.safety_mode"]
        stops = frame[(mode == "stopped") & (mode.shift() != "stopped")]  # each stop, with what was read as it began
        assert len(stops) and stops["light_barrier.broken"].astype(bool).any()
        assert bool((~stops["light_barrier.broken"].astype(bool)).any()) is stops_for_scanner


def test_a_scripts_system_added_as_a_module_is_recorded(tmp_path):
    class Ticks(cellsim.CellSystem):
        """Counts its own updates on a channel of the script's own, ``ticks.count``."""

        def __init__(self, number_type):
            super().__init__("ticks", 0.5)
            self._n = self.declare_channel("count", number_type, 0.0, description="updates so far")

        def update(self, context, xd):
            xd.get_mutable_vector(self._n).SetAtIndex(0, context.get_discrete_state(self._n).GetAtIndex(0) + 1)

    added = {}

    def extend(cell):
        number = cell.channels()["ground_truth.separation"][0].type  # a number channel's type, in metres
        added["ticks"] = cell.add("ticks", Ticks(number))
        with pytest.raises(KeyError, match="no channel 'nowhere.x'"):
            cell.channel("nowhere.x")
        with pytest.raises(KeyError, match="module 'robot' has no input 'throttle'; inputs: "):
            cell.module_input("robot.throttle")
        with pytest.raises(ValueError, match="carries 6 numbers"):
            cell.code_of("robot.joint_positions", 0.0)
        # an audit found these handed out, then ending the process at Build (Drake's check is no exception)
        with pytest.raises(KeyError, match="'robot.safety_mode_request' is driven already, by safety_controller."):
            cell.module_input("robot.safety_mode_request")
        for name in ("light_barrier", "ticks"):
            with pytest.raises(KeyError, match=f"already has a module or system named '{name}'"):
                cell.add(name, Ticks(number))

    run = cellsim.simulate(cellsim.load_scenario(WELDING), tmp_path / "ticks", duration=2.0, extend=extend)
    assert "ticks.count" in run.channels()  # recorded like any module's channel
    counts = run.series("ticks.count")["ticks.count"]
    assert list(counts.values) == [1.0, 2.0, 3.0, 4.0] and list(counts.times) == [0.0, 0.5, 1.0, 1.5]  # its updates in 2 s


def test_a_run_drawn_in_meshcat_from_a_script_draws_the_cell_and_records_the_same_run(tmp_path):
    meshcat = cellsim.open_meshcat()
    try:
        drawn = cellsim.simulate(cellsim.load_scenario(WELDING), tmp_path / "drawn", duration=0.5, meshcat=meshcat)
        assert meshcat.web_url().startswith("http://localhost:")
        assert meshcat.HasPath("/drake/visualizer/fixture/fence_north_outline")  # the cell, drawn
        assert drawn.summary.real_time_factor < 1.5  # paced to the wall clock
    finally:
        del meshcat
    plain = cellsim.simulate(cellsim.load_scenario(WELDING), tmp_path / "plain", duration=0.5)
    assert _rows(drawn.out / "blackbox.sqlite") == _rows(plain.out / "blackbox.sqlite")


def test_an_extra_logger_in_a_built_diagram_logs_a_channel_at_its_own_rate():
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.primitives import LogVectorOutput

    logs = {}

    def extend(cell):
        logs["separation"] = LogVectorOutput(cell.channel("ground_truth.separation"), cell.builder, 0.01)

    built = cellsim.build(cellsim.load_scenario(WELDING), extend=extend)
    simulator = Simulator(built.diagram)
    built.set_initial_state(simulator.get_mutable_context())
    simulator.AdvanceTo(1.0)
    log = logs["separation"].FindLog(simulator.get_context())
    assert log.num_samples() == 101 and 2.0 < log.data()[0, -1] < 4.0  # the operator starts well away


def test_the_cells_in_code_run_as_scripts(tmp_path):
    done = subprocess.run([sys.executable, str(ROOT / "diagrams" / "two_arm_cell.py"), "--out", str(tmp_path / "two"),
                           "--duration", "4"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "completed" in done.stdout and "ArmsApart: holds" in done.stdout
    assert (tmp_path / "two" / "blackbox.sqlite").is_file()


def test_the_cli_and_the_api_write_the_same_black_box(tmp_path):
    api_run = cellsim.simulate(cellsim.load_scenario(WELDING, ["seed=5"]), tmp_path / "api", duration=8.0)
    done = subprocess.run([sys.executable, "-m", "cellsim", "simulate", str(WELDING), "--set", "seed=5",
                           "--duration", "8", "--out", str(tmp_path / "cli"), "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode in (0, 1), done.stderr
    assert _rows(tmp_path / "cli" / "blackbox.sqlite") == _rows(api_run.out / "blackbox.sqlite")


def _comparable(results: dict) -> dict:
    """A campaign's results.json without what differs between two processes writing it (times, commands)."""
    drop = {"timing", "provenance", "wall_time", "command", "rerun", "created", "started", "finished"}

    def clean(value):
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items() if k not in drop}
        if isinstance(value, list):
            return [clean(v) for v in value]
        return value

    return clean(results)


@pytest.mark.slow
def test_campaign_falsify_and_verify_from_python_match_the_cli(tmp_path):
    seen = []
    outcome = cellsim.run_campaign(WELDING, tmp_path / "api", runs=3, duration=6.0, jobs=1, progress=seen.append)
    assert [p.done for p in seen] == [0, 1, 2, 3] and seen[-1].total == 3  # said as it starts, then per run
    done = subprocess.run([sys.executable, "-m", "cellsim", "campaign", str(WELDING), "--runs", "3", "--duration",
                           "6", "--jobs", "1", "--out", str(tmp_path / "cli"), "--quiet"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode in (0, 1), done.stderr
    cli = json.loads((tmp_path / "cli" / "results.json").read_text())
    assert _comparable(outcome.results) == _comparable(cli)
    checked = cellsim.check_campaign(tmp_path / "api")
    assert checked.bounds["overall"]["runs"] == 3 and not checked.uncheckable

    steps = []
    search = cellsim.falsify(WELDING, tmp_path / "search", budget=4, method="random", duration=6.0,
                             conditions=["Final:Cell"], progress=steps.append)
    assert steps and steps[-1].done == 4 and search.results["search"]["method"] == "random"
    assert cellsim.check_campaign(tmp_path / "search").bounds is None  # a search's runs bound nothing

    stages = []
    result = cellsim.verify_cell(WELDING, progress=stages.append)
    assert stages and result.results and result.model.cell.assumptions
    done = subprocess.run([sys.executable, "-m", "cellsim", "verify", str(WELDING), "--json", "--no-replay"],
                          capture_output=True, text=True, timeout=600)
    cli = json.loads(done.stdout)
    assert {p["name"]: p["holds"] for p in cli["properties"]} == {r.prop.name: r.holds for r in result.results}


def test_a_campaign_of_a_scenario_built_in_code_asks_for_its_file(tmp_path):
    from welding_cell import SCENARIOS, welding_cell

    sf = cellsim.scenario_in_code(welding_cell(), base_dir=SCENARIOS)
    with pytest.raises(cellsim.ConfigError, match="save it first"):
        cellsim.run_campaign(sf, tmp_path / "c", runs=1)
    with pytest.raises(cellsim.ConfigError, match="save it first"):
        cellsim.verify_cell(sf, replay_in=tmp_path / "w")
    (tmp_path / "saved").mkdir()
    saved = cellsim.save_scenario(sf, tmp_path / "saved" / "welding_cell.yaml")
    again = cellsim.load_scenario(saved)
    assert again.scenario.entities["robot"].named_poses == sf.scenario.entities["robot"].named_poses


def test_the_two_arm_cell_in_code_runs_and_its_own_conditions_hold(tmp_path):
    from two_arm_cell import SCENARIOS, two_arm_cell

    run = cellsim.simulate(cellsim.scenario_in_code(two_arm_cell(), base_dir=SCENARIOS), tmp_path / "two")
    assert run.verdicts == {"ArmsApart": "holds", "PartHanded": "holds", "NoHarm": "holds", "NoClamping": "holds"}
    clearance = run.series("ground_truth.clearance_loader_assembler")["ground_truth.clearance_loader_assembler"]
    assert 0.05 < min(clearance.values) < 0.6  # they work at one fixture: near, never touching


API_COMMANDS = ("simulate", "check", "campaign", "falsify", "verify", "scenario", "live")
"""The commands whose work the API does. The others run tools beside the twin (the bridge daemon, the emulator,
keys, the dashboard, replays, exports, the module catalogue, twin-mode requests)."""
FRONT_END = {"cellsim.api", "cellsim", "cellsim.numbers", "cellsim.visual.serve"}
"""What those commands may import of cellsim besides its cli package: the API, the numbers' formatting for
people, and the terminal's handling of a Meshcat server (waiting for Enter)."""


def test_the_clis_commands_import_the_api_not_internals():
    for command in API_COMMANDS:
        tree = ast.parse((ROOT / "cellsim" / "cli" / f"{command}.py").read_text())
        used = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
        used |= {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
        internal = {m for m in used if m.startswith("cellsim") and not m.startswith("cellsim.cli")} - FRONT_END
        assert not internal, f"cellsim/cli/{command}.py imports {sorted(internal)}"


def test_the_api_reference_is_what_the_code_says():
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "api_reference.py"), "--check"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_the_scripting_guide_names_only_public_names():
    """Every ``cellsim.<name>`` the guide uses is in ``cellsim.__all__``."""
    import re

    text = (ROOT / "docs" / "scripting.md").read_text()
    used = set(re.findall(r"\bcellsim\.([A-Za-z_]+)\(", text)) | set(re.findall(r"`cellsim\.([A-Za-z_]+)`", text))
    used.discard("__all__")
    assert used and used <= set(cellsim.__all__), used - set(cellsim.__all__)


@pytest.mark.slow
def test_a_script_with_no_main_guard_runs_a_campaign_on_two_workers(tmp_path):
    """The scripting guide's campaign, written as a plain script (no ``if __name__ == "__main__":``): its spawned
    workers must not run the script again (they did, found the folder taken, and died: 'a worker process died')."""
    script = tmp_path / "campaign.py"
    script.write_text(
        "import cellsim\n"
        f"outcome = cellsim.run_campaign({str(ROOT / 'scenarios' / 'welding_cell.yaml')!r}, {str(tmp_path / 'c')!r},\n"
        "                               runs=2, jobs=2, duration=2.0)\n"
        "print('runs', outcome.results['totals']['runs'])\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "runs 2" in done.stdout and len(json.loads((tmp_path / "c" / "results.json").read_text())["runs"]) == 2


def test_falsify_from_a_script_runs_the_search_the_command_runs_by_default(monkeypatch, tmp_path):
    """``cellsim.falsify`` works "as ``cellsim falsify`` does": with no method named, the same search (qd)."""
    import cellsim.campaign.falsify as search
    from cellsim.cli import main

    plans = []

    def searched(plan, out, **kw):
        plans.append(plan)
        raise search.CampaignError("stopped here: the plan is what is asserted")

    monkeypatch.setattr(search, "run_falsify", searched)
    with pytest.raises(search.CampaignError):
        cellsim.falsify(WELDING, tmp_path / "api", budget=4)
    assert main(["falsify", str(WELDING), "--budget", "4", "--out", str(tmp_path / "cli"), "--quiet"]) == 2
    assert [plan.method for plan in plans] == ["qd", "qd"]


def test_a_scenario_changed_in_place_is_checked_as_a_file_before_any_folder(tmp_path):
    """A script sets a wrong type or an out-of-range value on a loaded scenario: one ConfigError naming the key, as
    a file would get, and no folder made (an audit found a TypeError deep in the operator, and a lock file left)."""
    for key, value, problem in (("walking_speed", "fast", "expected a number"), ("walking_speed", -1.0, "out of range")):
        sf = cellsim.load_scenario(WELDING)
        setattr(sf.scenario.entities["operator"], key, value)
        with pytest.raises(cellsim.ConfigError, match=f"as changed in code.*entities.operator.{key}: .*{problem}"):
            cellsim.simulate(sf, tmp_path / "run", duration=1.0)
    sf = cellsim.load_scenario(WELDING)
    sf.scenario.time_step = 0.0
    with pytest.raises(cellsim.ConfigError, match="time_step"):
        cellsim.simulate(sf, tmp_path / "run", duration=1.0)
    assert list(tmp_path.iterdir()) == []


def test_work_that_reads_the_file_refuses_a_scenario_changed_in_code(tmp_path):
    """A campaign's workers and a witness's replay read the scenario's file: a scenario changed in place since it was
    loaded would be silently dropped (the audit's campaign judged the file's 16 conditions, not the script's one)."""
    sf = cellsim.load_scenario(WELDING)
    del sf.scenario.behaviours["safety_controller"]
    with pytest.raises(cellsim.ConfigError, match="changed in code since it was loaded.*save it first"):
        cellsim.run_campaign(sf, tmp_path / "c", runs=1, duration=1.0)
    with pytest.raises(cellsim.ConfigError, match="changed in code since it was loaded.*save it first"):
        cellsim.falsify(sf, tmp_path / "f", budget=1, duration=1.0)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("call, message", [
    (lambda out: cellsim.run_campaign(WELDING, out, runs=0), "runs: must be a whole number in \\[1, 100,000\\], got 0"),
    (lambda out: cellsim.run_campaign(WELDING, out, jobs=0), "jobs: must be a whole number"),
    (lambda out: cellsim.run_campaign(WELDING, out, duration=float("nan")), "duration \\(the argument\\): nan"),
    (lambda out: cellsim.run_campaign(WELDING, out, runs=2, until_bound=0.5), "takes 5 runs without a violation"),
    (lambda out: cellsim.run_campaign(WELDING, out, until_bound=2.0), "must be a probability in \\(0, 1\\)"),
    (lambda out: cellsim.falsify(WELDING, out, budget=0), "budget: must be a whole number"),
    (lambda out: cellsim.falsify(WELDING, out, budget=2, conditions="NoHarm"), "a list of condition names"),
    (lambda out: cellsim.simulate(WELDING, out, seed=1.5), "1.5 is not a whole number"),
    (lambda out: cellsim.simulate(WELDING, out, seed=True), "True is not a whole number"),
    (lambda out: cellsim.simulate(WELDING, out, duration=1e-9), "shorter than one plant step"),
])
def test_a_scripts_bad_argument_is_one_config_error_and_writes_nothing(tmp_path, call, message):
    with pytest.raises(cellsim.ConfigError, match=message):
        call(tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


def test_a_scenario_built_in_code_is_never_saved_over_a_file_it_uses(tmp_path):
    import shutil

    from two_arm_cell import two_arm_cell

    shutil.copytree(ROOT / "scenarios" / "models", tmp_path / "models")
    before = (tmp_path / "models" / "ur10.urdf").read_bytes()
    sf = cellsim.scenario_in_code(two_arm_cell(), base_dir=tmp_path)
    with pytest.raises(cellsim.OverwritesInput):
        cellsim.save_scenario(sf, tmp_path / "models" / "ur10.urdf")
    assert (tmp_path / "models" / "ur10.urdf").read_bytes() == before


def test_a_run_opened_from_its_folder_says_its_finding_before_its_verdicts_are_read(tmp_path):
    run = cellsim.simulate(WELDING, tmp_path / "run", seed=0, duration=6.0)  # Final:Tbl: at the table at 6 s
    assert run.finding
    opened = cellsim.Run.open(tmp_path / "run")
    assert opened.checked is None and opened.finding  # judged when asked (it read False before)
    with pytest.raises(KeyError, match="no condition 'Nope' judged this run; its conditions: "):
        opened.explain("Nope")


def test_a_run_whose_diagram_a_script_extended_says_so_in_its_record(tmp_path):
    """Its scenario.yaml alone builds the cell without the script's systems: the file and the black box say so."""
    def extend(cell):
        pass

    run = cellsim.simulate(WELDING, tmp_path / "run", duration=1.0, extend=extend)
    header = (run.out / "scenario.yaml").read_text().split("\n\n")[0]
    assert "extended by test_api.test_a_run_whose_diagram_a_script_extended_says_so_in_its_record.<locals>.extend" in header
    db = sqlite3.connect(run.out / "blackbox.sqlite")
    (value,) = db.execute("SELECT value FROM metadata WHERE key = 'extended_by'").fetchone()
    db.close()
    assert json.loads(value).endswith("<locals>.extend")


def test_a_runs_readers_take_what_a_script_most_likely_gives_and_refuse_the_rest_in_words(tmp_path):
    run = cellsim.simulate(WELDING, tmp_path / "run", duration=1.0)
    assert list(run.dataframe("ground_truth.separation").columns) == ["ground_truth.separation"]  # one name
    for period in (0.0, -1.0, float("nan"), 1e-12):
        with pytest.raises(ValueError, match="period"):
            run.dataframe(["ground_truth.separation"], period=period)
    assert cellsim.check(tmp_path / "run", WELDING).result.verdicts  # a scenario's path, as elsewhere
    assert "NoHarm" in cellsim.default_conditions(WELDING)
    with pytest.raises(cellsim.ConfigError, match="a list of PATH=VALUE strings"):
        cellsim.load_scenario(WELDING, "seed=3")


def test_a_system_a_script_forgot_to_wire_is_a_config_error_before_the_run_folder_is_touched(tmp_path):
    """An audit found Drake noticing an unconnected input only once the run had started, its folder written and
    marked failed (and then refused for the fixed script as holding a run)."""
    from pydrake.systems.framework import LeafSystem

    class Gate(LeafSystem):
        def __init__(self):
            super().__init__()
            self.DeclareVectorInputPort("curtain", 1)
            self.DeclareVectorOutputPort("mode", 1, lambda context, out: out.SetAtIndex(0, 0.0))

    def extend(cell):
        cell.builder.AddNamedSystem("gate", Gate())  # its own input connected to nothing

    with pytest.raises(cellsim.ConfigError, match="input 'curtain' of system 'gate' is connected to nothing"):
        cellsim.simulate(cellsim.load_scenario(WELDING), tmp_path / "run", duration=1.0, extend=extend)
    assert not (tmp_path / "run").exists()
    # a Drake system too (a review found Drake's own skipped altogether): a log of nothing
    from pydrake.systems.primitives import VectorLogSink

    with pytest.raises(cellsim.ConfigError, match="extend: input 'data' of system 'log' is connected to nothing"):
        cellsim.simulate(cellsim.load_scenario(WELDING), tmp_path / "run", duration=1.0,
                         extend=lambda cell: cell.builder.AddNamedSystem("log", VectorLogSink(1)))
    assert not (tmp_path / "run").exists()



def test_a_run_that_cannot_be_judged_is_no_run_without_a_finding(tmp_path):
    """An audit found Run.finding False for a run that failed before it recorded anything: every CheckError was taken
    for 'no conditions'. Only that case is; a run that cannot be judged says so."""
    from pydrake.systems.framework import LeafSystem

    from cellsim.validation.check import CheckError

    class Breaks(LeafSystem):
        def __init__(self):
            super().__init__()
            self.DeclareInitializationPublishEvent(self._fail)

        def _fail(self, context):
            raise RuntimeError("a script's system broke")

    def extend(cell):
        cell.builder.AddNamedSystem("breaks", Breaks())

    with pytest.raises(RuntimeError, match="broke"):
        cellsim.simulate(cellsim.load_scenario(WELDING), tmp_path / "run", duration=1.0, extend=extend)
    assert cellsim.Run.open(tmp_path / "run").finding  # what it recorded (t = 0) is judged: inconclusive, no pass
    with sqlite3.connect(tmp_path / "run" / "blackbox.sqlite") as db:  # as a run killed before its first commit
        db.execute("DELETE FROM messages")
    run = cellsim.Run.open(tmp_path / "run")
    assert run.summary.status == "failed"
    with pytest.raises(CheckError, match="before it recorded anything"):
        run.finding


@pytest.mark.parametrize("args, said", [
    (dict(seed=-1), "seed argument: -1 is out of range"),
    (dict(seed="x"), "seed argument: 'x' is not a whole number"),
    (dict(duration=-5), "duration argument: -5 is out of range"),
    (dict(duration=float("nan")), "duration argument: nan is out of range"),
])
def test_a_scripts_bad_seed_or_duration_is_a_config_error_naming_its_argument(tmp_path, args, said):
    """An audit found build() passing a bad seed to numpy (ValueError) and a negative duration through, and simulate()
    naming a script's argument as the command line's --duration."""
    with pytest.raises(cellsim.ConfigError, match=re.escape(said)):
        cellsim.build(cellsim.load_scenario(WELDING), **args)
    with pytest.raises(cellsim.ConfigError, match=re.escape(said)):
        cellsim.simulate(cellsim.load_scenario(WELDING), tmp_path / "run", **args)
    assert not (tmp_path / "run").exists()


def test_a_damaged_black_box_read_from_a_script_is_a_black_box_error(tmp_path):
    """An audit found Run.open, series and dataframe raising TypeError, JSONDecodeError or AttributeError on a damaged
    black box, where the docs promise BlackBoxError (and cellsim check says 'corrupt black box')."""
    run = cellsim.simulate(cellsim.load_scenario(WELDING), tmp_path / "good", duration=1.0)
    box = run.out / "blackbox.sqlite"
    for damage, reader in [
        ("UPDATE messages SET payload = 'null' WHERE channel = 'robot.safety_mode'", "open"),
        ("UPDATE messages SET payload = '[1, 2]' WHERE channel = 'robot.joint_positions'", "series"),
        ("UPDATE messages SET payload = '{bad' WHERE channel = 'robot.safety_mode'", "open"),
        ("UPDATE metadata SET value = '[1, 2]' WHERE key = 'hazards'", "open"),
    ]:
        copy = tmp_path / f"damaged-{reader}-{abs(hash(damage))}"
        shutil.copytree(run.out, copy)
        with sqlite3.connect(copy / "blackbox.sqlite") as db:
            db.execute(damage)
        with pytest.raises(cellsim.BlackBoxError, match="corrupt black box"):
            opened = cellsim.Run.open(copy)
            opened.series("robot.joint_positions")
            opened.dataframe()
    assert box.exists()
