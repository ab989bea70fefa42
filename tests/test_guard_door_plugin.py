"""A module kind written outside cellsim: the guard-door plug-in (examples/guard_door), installed by pip.

One folder and one entry point bring everything cellsim needs of a kind (config, system, abstraction
for ``verify``, physical protocol for the bridge, Meshcat cues), with no edit to cellsim: installed
into a folder of its own, it is listed by ``cellsim modules``, and its example cell is simulated,
verified, bridged and drawn. Outputs are read back with other libraries than the ones that wrote them
(sqlite3 for the black box, stormpy for the PRISM model)."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PLUGIN = ROOT / "examples" / "guard_door"
CELL = PLUGIN / "cell" / "machine_tending.yaml"
BRIDGE = PLUGIN / "cell" / "bridge.yaml"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The plug-in installed by pip into a folder of its own (from a copy: the build leaves the repo clean)."""
    work = tmp_path_factory.mktemp("guard_door")
    source = work / "source"
    shutil.copytree(PLUGIN, source, ignore=shutil.ignore_patterns("cell", "build", "*.egg-info"))
    site = work / "site"
    done = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                           "--no-index", "--target", str(site), str(source)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert (site / "cellsim_guard_door" / "kind.py").is_file()
    return site


def run(site: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env, timeout=timeout, cwd=ROOT)


def test_cellsim_modules_lists_the_installed_kind_and_its_parameters(site):
    listed = run(site, "-m", "cellsim", "modules", "--json")
    assert listed.returncode == 0, listed.stderr
    kinds = {k["kind"]: k for k in json.loads(listed.stdout)["kinds"]}
    assert kinds["guard_door"]["section"] == "entities"
    assert "interlocked guard door" in kinds["guard_door"]["summary"]
    one = json.loads(run(site, "-m", "cellsim", "modules", "guard_door", "--json").stdout)
    names = [p["name"] for p in one["parameters"]]
    assert names[:4] == ["center", "size", "hinge", "period"] and "twin.mode" in names
    assert "open" in json.dumps(one)  # its channel, documented by the kind


def test_without_the_plugin_its_cell_is_one_error_naming_the_kind():
    done = subprocess.run([sys.executable, "-m", "cellsim", "scenario", "check", str(CELL)], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "entities.press_door.kind: unknown kind 'guard_door'" in done.stderr


def test_its_cell_simulates_and_the_open_door_stops_the_press(site, tmp_path):
    out = tmp_path / "run"
    done = run(site, "-m", "cellsim", "simulate", str(CELL), "--out", str(out), "--quiet")
    assert done.returncode == 0, done.stderr
    with sqlite3.connect(out / "blackbox.sqlite") as db:  # read back with sqlite3, not cellsim's reader
        rows = db.execute("SELECT t, channel, payload FROM messages WHERE channel IN "
                          "('press_door.open', 'press.activity', 'safety_controller.DOOR') ORDER BY t").fetchall()
    door, press, hazard, seen = False, "open", [], []
    for t, channel, payload in rows:
        value = json.loads(payload)["value"]
        if channel == "press_door.open":
            door = bool(value)
            seen.append(door)
        elif channel == "press.activity":
            press = value
            assert not (door and press == "pressing"), f"the press strokes at {t} s with its door open"
        else:
            hazard.append(value)
    assert True in seen and seen[-1] is False  # the operator reached in through the door, and left
    assert "guarded" in hazard and "harm" not in hazard and hazard[-1] == "idle"


def test_verify_checks_the_kinds_abstraction_and_stormpy_reads_the_exported_model(site, tmp_path):
    import stormpy

    prism = tmp_path / "model.prism"
    done = run(site, "-m", "cellsim", "verify", str(CELL), "--out", str(tmp_path / "verify"), "--export", str(prism),
               "--json")
    assert done.returncode == 0, done.stderr
    results = json.loads(done.stdout)
    assert [(p["name"], p["holds"]) for p in results["properties"]] == [("DOOR:mishap", True)] and results["holds"]
    program = stormpy.parse_prism_program(str(prism))
    model = stormpy.build_model(program)
    assert model.nr_states == results["states"] > 1
    assert "press_door" in prism.read_text()  # the door's reading, from the kind's abstraction


BRIDGE_SCRIPT = textwrap.dedent('''
    import json, os, sys
    from cellsim.bridges.config import load_bridge
    from cellsim.bridges.daemon import Bridge
    from cellsim.bridges.e2e import protect
    from cellsim.bridges.secoc import Authenticator, message_key

    class Session:  # records what the daemon publishes, by key
        def __init__(self):
            self.published = {}
        def declare_publisher(self, key):
            session = self
            class Publisher:
                def put(self, payload):
                    session.published.setdefault(key, []).append(json.loads(payload))
            return Publisher()
        def declare_subscriber(self, *args, **kwargs):
            return None
        def liveliness(self):
            return self
        def declare_token(self, key):
            return None

    loaded = load_bridge(sys.argv[1])
    key = os.urandom(16)
    session = Session()
    bridge = Bridge(loaded, session, can_key=key)
    message = loaded.database.get_message_by_name("GuardDoorStateAuthenticated")
    signer = Authenticator(message, message_key(key, message.frame_id), loaded.config.freshness_tick)
    judged = []
    for counter, is_open in enumerate([0, 1, 1]):
        judged.append(bridge.handle(message.frame_id, protect(message, {"Open": is_open}, counter, signer), now=0.02 * counter).good)
    bad = bytearray(protect(message, {"Open": 0}, 3, signer))
    bad[0] ^= 0xFF
    judged.append(bridge.handle(message.frame_id, bytes(bad), now=0.06).fault.value)
    print(json.dumps({"judged": judged, "published": session.published["cellsim/machine_tending/physical/press_door"]}))
''')


def test_the_bridge_maps_the_door_switch_frame_to_the_kinds_sample_field(site, tmp_path):
    script = tmp_path / "bridge_door.py"
    script.write_text(BRIDGE_SCRIPT)
    done = run(site, str(script), str(BRIDGE), timeout=120)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["judged"] == [True, True, True, "crc"]
    published = out["published"]
    assert [p.get("fields") for p in published[:3]] == [{"open": False}, {"open": True}, {"open": True}]
    assert published[3]["failed"] == "crc"  # the twin's door fails safe (reads open) on it


CUES_SCRIPT = textwrap.dedent('''
    import base64, json, re, sys
    from pathlib import Path
    from cellsim.scenario import load_scenario
    from cellsim.simulation import simulate
    from cellsim.visual.replay import replay
    from cellsim.visual.serve import open_meshcat

    out = Path(sys.argv[2])
    simulate(load_scenario(sys.argv[1]), out, duration=21.0)
    meshcat = open_meshcat()
    played = replay(out, meshcat, at=0.0)
    sent = [base64.b64decode(b) for b in re.findall(r'base64,([A-Za-z0-9+/=]+)"', meshcat.StaticHtml())]
    animation = b"".join(m for m in sent if b"set_animation" in m)
    print(json.dumps({"open_drawn": b"/cellsim/press_door/door/open/0" in animation,
                      "closed_drawn": b"/cellsim/press_door/door/closed/0" in animation,
                      "shown_at_end": played.cell.cue_visualizer.drawer.visible_look("press_door/door")}))
''')


def test_its_meshcat_cue_draws_the_door_open_while_the_operator_reaches_in(site, tmp_path):
    script = tmp_path / "cues_door.py"
    script.write_text(CUES_SCRIPT)
    done = run(site, str(script), str(CELL), str(tmp_path / "run"), timeout=300)
    assert done.returncode == 0, done.stderr
    # at 21 s the operator still reaches in (19 s to 23.4 s): the door is drawn open
    assert json.loads(done.stdout.strip().splitlines()[-1]) == {"open_drawn": True, "closed_drawn": True,
                                                                  "shown_at_end": "open"}
