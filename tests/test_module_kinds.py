"""Module kinds: a registry found through entry points, plug-ins that need no change to cellsim,
and ``cellsim modules`` generated from the kinds' own declarations."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cellsim import registry
from cellsim.kinds_doc import describe
from cellsim.scenario import export_scenario, load_scenario
from cellsim.blackbox import BlackBox

from conftest import ROOT, WELDING_CELL, welding_cell

PLUGIN = '''
"""A plug-in module kind: a beacon that counts its updates."""
from dataclasses import dataclass
from typing import Literal

from cellsim.channels import number_type
from cellsim.kind import ModuleKind
from cellsim.systems import CellSystem, read_scalar, write_scalar


@dataclass
class BeaconConfig:
    kind: Literal["beacon"]
    period: float = 0.5
    """How often it blinks (s)."""


class Beacon(CellSystem):
    def __init__(self, name, cfg):
        super().__init__(name, cfg.period)
        self._blinks = self.declare_channel("blinks", number_type(None), 0.0)

    def update(self, context, xd):
        write_scalar(xd, self._blinks, read_scalar(context, self._blinks) + 1)


class BeaconKind(ModuleKind):
    name = "beacon"
    section = "behaviours"
    config = BeaconConfig
    stage = 10
    summary = "Counts its updates."
    channels = (("blinks", "number", "updates so far"),)

    def build(self, cell, name, cfg):
        return cell.add(name, Beacon(name, cfg))


@dataclass
class PlainConfig:
    kind: str = "boom"


class Boom(ModuleKind):  # its build fails
    name, section, config, summary = "boom", "behaviours", PlainConfig, "Fails to build."

    def build(self, cell, name, cfg):
        raise RuntimeError("my build blew up")


class CheckBoom(Boom):  # its check fails
    name = "check_boom"

    def check(self, sf, name, cfg):
        raise RuntimeError("my check blew up")


class PrepBoom(Boom):  # its prepare (before the plant is finalised) fails
    name = "prep_boom"

    def prepare(self, cell, name, cfg):
        raise RuntimeError("my prepare blew up")


class NoSection(Boom):  # no section of the scenario's
    name, section = "no_section", None


@dataclass
class NeedsConfig:
    level: float
    kind: str = "needs_arg"


class NeedsArg(Boom):  # adds a module to every scenario whose config cannot be made from defaults
    name, section, config, default_module = "needs_arg", "services", NeedsConfig, "needs_arg"
'''


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """A plug-in package installed the way pip installs one: a package and its dist-info."""
    site = tmp_path_factory.mktemp("site")
    (site / "cellsim_beacon").mkdir()
    (site / "cellsim_beacon" / "__init__.py").write_text(PLUGIN)
    info = site / "cellsim_beacon-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: cellsim-beacon\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[cellsim.modules]\nbeacon = cellsim_beacon:BeaconKind\nbroken = cellsim_beacon.missing:KIND\n"
        "boom = cellsim_beacon:Boom\ncheck_boom = cellsim_beacon:CheckBoom\nno_section = cellsim_beacon:NoSection\n"
        "prep_boom = cellsim_beacon:PrepBoom\n"
        "needs_arg = cellsim_beacon:NeedsArg\n"
    )
    return site


def cellsim(site: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "cellsim.cli", *args], capture_output=True, text=True, env=env, timeout=300)


def scenario_with(tmp_path: Path, name: str, module: dict) -> Path:
    data = yaml.safe_load(export_scenario(load_scenario(WELDING_CELL), destination_dir=tmp_path))
    data["behaviours"][name] = module
    path = tmp_path / "with_plugin.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_a_plugin_kind_is_used_in_a_scenario_without_touching_cellsim(site, tmp_path):
    scenario = scenario_with(tmp_path, "beacon", {"kind": "beacon", "period": 0.5})
    out = tmp_path / "run"
    done = cellsim(site, "simulate", str(scenario), "--out", str(out), "--duration", "3", "--quiet")
    assert done.returncode == 0, done.stderr
    with BlackBox(out / "blackbox.sqlite") as bb:
        blinks = bb.series("beacon.blinks")
    assert blinks.values[-1] == 6.0 and list(blinks.times[:2]) == [0.0, 0.5]


def test_modules_lists_the_plugin_and_names_a_broken_one(site):
    listed = cellsim(site, "modules", "--json")
    assert listed.returncode == 0, listed.stderr
    data = json.loads(listed.stdout)
    assert {"kind": "beacon", "section": "behaviours", "summary": "Counts its updates."} in data["kinds"]
    assert any("cellsim_beacon.missing:KIND" in e and "failed to load" in e for e in data["errors"])
    one = json.loads(cellsim(site, "modules", "beacon", "--json").stdout)
    assert one["parameters"] == [{"name": "period", "type": "number", "default": "0.5", "range": "finite", "doc": "How often it blinks (s)."}]


def test_a_scenario_using_a_broken_plugin_is_one_line_naming_it(site, tmp_path):
    scenario = scenario_with(tmp_path, "broken_one", {"kind": "broken"})
    out = tmp_path / "run"
    done = cellsim(site, "simulate", str(scenario), "--out", str(out))
    assert done.returncode == 2
    err = done.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert f"{scenario}:" in err and "behaviours.broken_one.kind" in err and "cellsim_beacon.missing:KIND" in err
    assert not out.exists()


@pytest.mark.parametrize("kind, command, said", [
    # (the audit's: each was a traceback, exit 1, the plug-in named nowhere)
    ("boom", "simulate", "the kind 'boom' (plug-in cellsim_beacon) failed to build module 'extra': RuntimeError: "
                         "my build blew up"),
    ("check_boom", "check", "the kind 'check_boom' (plug-in cellsim_beacon) failed to check module 'extra': "
                            "RuntimeError: my check blew up"),
    ("prep_boom", "simulate", "the kind 'prep_boom' (plug-in cellsim_beacon) failed to prepare module 'extra': "
                              "RuntimeError: my prepare blew up"),
    ("no_section", "check", "its section is None"),
    ("needs_arg", "check", "its config cannot be made from defaults"),
])
def test_a_plugin_that_fails_or_is_malformed_is_one_line_naming_it(site, tmp_path, kind, command, said):
    scenario = scenario_with(tmp_path, "extra", {"kind": kind})
    out = tmp_path / "run"
    args = ["simulate", str(scenario), "--out", str(out), "--duration", "1"] if command == "simulate" else \
        ["scenario", "check", str(scenario)]
    done = cellsim(site, *args)
    err = done.stderr.strip()
    assert done.returncode == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert said in err and "behaviours.extra" in err
    assert not out.exists()


def test_a_malformed_plugin_fails_only_the_scenarios_that_use_it(site):
    """The audit's: one plug-in adding a default module whose config needs a value crashed every scenario."""
    done = cellsim(site, "scenario", "check", str(WELDING_CELL))
    assert done.returncode == 0, done.stderr


def test_an_unknown_kind_suggests_the_nearest(tmp_path, capsys):
    from cellsim.cli import main

    scenario = scenario_with(tmp_path, "gt2", {"kind": "ground_trth"})
    assert main(["scenario", "check", str(scenario)]) == 2
    err = capsys.readouterr().err
    assert "behaviours.gt2.kind: unknown kind 'ground_trth'" in err and "did you mean 'ground_truth'?" in err


def test_a_kind_in_the_wrong_section_is_refused(tmp_path, capsys):
    from cellsim.cli import main

    scenario = scenario_with(tmp_path, "arm2", {"kind": "robot", "model": "x.urdf", "named_poses": {}})
    assert main(["scenario", "check", str(scenario)]) == 2
    assert "kind 'robot' is one of the entities, not of the behaviours" in capsys.readouterr().err


def test_every_kind_documents_the_channels_its_systems_publish(tmp_path):
    """The docs of ``cellsim modules`` against the systems two cells build (every shipped kind)."""
    from cellsim.diagrams.cell import build_cell
    from test_area_scanner import scanner_cell
    from test_process import press_cell

    seen = set()
    for sf in (welding_cell(), load_scenario(press_cell(tmp_path)), load_scenario(scanner_cell(tmp_path)),
               load_scenario(ROOT / "scenarios" / "assembly_bench.yaml")):
        built = build_cell(sf, seed=0, duration=1.0, record=False)
        for section in registry.SECTIONS:
            for name, cfg in getattr(sf.scenario, section).items():
                kind = registry.kind_of(cfg)
                documented = {signal for signal, _, _ in kind.channels}
                published = {spec.signal for spec, _ in getattr(built.modules.get(name), "channels", [])}
                if any("<" in s for s in documented):  # per risk-model variable, flag or robot pair: templates
                    fixed = {s for s in documented if "<" not in s}
                    assert fixed <= published, (kind.name, fixed - published)
                else:  # a channel documented "only with ..." may be absent
                    optional = {signal for signal, _, text in kind.channels if text.startswith("only with")}
                    assert published <= documented and documented - published <= optional, (kind.name, published ^ documented)
                seen.add(kind.name)
    assert seen == set(registry.kind_names())


def test_each_entitys_protocol_declared_by_its_kind_is_what_its_built_system_speaks(tmp_path):
    """The protocol a kind declares from its config alone (what the bridge daemon learns, building
    nothing) against the built systems of four cells: the same fields in the same order, the same types
    (an enum's values, a boolean, a number), the same safe command."""
    from cellsim.codec import FieldCodec
    from cellsim.diagrams.cell import build_cell
    from test_area_scanner import scanner_cell

    def described(types) -> list:
        return [t.domain() for t in types]

    seen = set()
    for sf in (welding_cell(), load_scenario(ROOT / "scenarios" / "palletising_cell.yaml"),
               load_scenario(scanner_cell(tmp_path)), load_scenario(ROOT / "scenarios" / "assembly_bench.yaml"),
               load_scenario(ROOT / "scenarios" / "two_operators.yaml")):
        built = build_cell(sf, seed=0, duration=1.0, record=False)
        for name, cfg in sf.scenario.entities.items():
            protocol, system = registry.kind_of(cfg).protocol(name, cfg), built.modules[name]
            samples, commands = FieldCodec.samples_of(system), FieldCodec.commands_of(system)
            assert [n for n, _ in protocol.samples] == list(samples.names), name
            assert described(t for _, t in protocol.samples) == described(samples.types), name
            assert [n for n, _ in protocol.commands] == list(commands.names), name
            assert described(t for _, t in protocol.commands) == described(commands.types), name
            safe = commands.fields([system.safe_command()[f] for f in commands.names])
            assert protocol.safe == safe, name
            seen.add(cfg.kind)
    assert seen == set(registry.kind_names("entities"))
    assert all(registry.get(k).protocol("x", None) is None for k in registry.kind_names("behaviours"))


def test_every_kind_documents_the_inputs_others_drive(tmp_path):
    """Every typed input of a built system (what a safety controller's commands may drive) is documented,
    and every documented input exists: the curtain's reset only with its interlock, as it says."""
    from cellsim.diagrams.cell import build_cell

    from test_process import press_cell

    seen = set()
    for sf in (welding_cell(), load_scenario(press_cell(tmp_path)), load_scenario(ROOT / "scenarios" / "palletising_cell.yaml"),
               load_scenario(ROOT / "scenarios" / "assembly_bench.yaml")):
        built = build_cell(sf, seed=0, duration=1.0, record=False)
        for section in registry.SECTIONS:
            for name, cfg in getattr(sf.scenario, section).items():
                kind, system = registry.kind_of(cfg), built.modules.get(name)
                if system is None:
                    continue
                documented = {i for i, _, _ in kind.inputs if not i.startswith("<")}
                typed = set(getattr(system, "input_types", {})) - set(getattr(cfg, "alerts", ()))
                ports = {system.get_input_port(k).get_name() for k in range(system.num_input_ports())}
                optional = {i for i, _, text in kind.inputs if text.startswith("only with")}
                assert typed <= documented and documented - optional <= ports, (kind.name, typed, documented, ports)
                seen.add(kind.name)
    assert {"robot", "machine", "operator", "process", "light_barrier"} <= seen


def test_every_parameter_of_every_shipped_kind_says_what_it_means():
    undocumented = [
        f"{name}.{p['name']}" for name in registry.kind_names() for p in describe(name)["parameters"] if not p["doc"]
    ]
    assert undocumented == []


def test_modules_kind_shows_inputs_and_wraps_long_keys_rather_than_cutting_them():
    """Issue 23: the tables cut key names at 80 columns (steps.<i>.ope…) and listed no inputs."""
    import os
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "cellsim", "modules", "machine"], capture_output=True, text=True,
                          timeout=60, cwd=ROOT, env={**os.environ, "COLUMNS": "80"})
    assert proc.returncode == 0 and "…" not in proc.stdout, proc.stdout
    assert max(len(line) for line in proc.stdout.splitlines()) <= 80
    inputs = proc.stdout[proc.stdout.index("inputs (driven as NAME.input"):]
    for name in ("safety_mode_request", "activity_request", "command"):
        assert f"│ {name}" in inputs, inputs
    # the longest key, folded over lines, is all there
    name = max((p["name"] for p in describe("machine")["parameters"]), key=len)
    first_column = "".join(line.split("│")[1].strip() for line in proc.stdout.splitlines() if line.startswith("│"))
    assert name in first_column
