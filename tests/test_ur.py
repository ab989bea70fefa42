"""A UR controller over RTDE: the wire, the program's registers, and the daemon's link to a controller."""

from __future__ import annotations

import contextlib
import itertools
import json
import queue
import select
import struct
import threading
import time

import pytest

from cellsim.bridges.config import load_bridge
from cellsim.bridges.daemon import Bridge
from cellsim.config.typed_yaml import ConfigError
from cellsim.ur import rtde
from cellsim.ur.controller import RtdeServer
from cellsim.ur.program import OutOfRange
from cellsim.vocabulary import TwinMode

from live_processes import free_port
from test_bridge import e2e_only_text, sessions  # noqa: F401 - the fixture

MODES = ("normal", "hguid", "ssmon", "pflim", "srmst", "stopped")


def ur_config(tmp_path, port: int, extra: str = "") -> str:
    """The E2E-only welding bridge with its robot over RTDE on loopback ``port``."""
    path = tmp_path / "bridge_ur.yaml"
    path.write_text(e2e_only_text() + f"    rtde:\n      port: {port}\n      reconnect_after: 0.2\n{extra}")
    return str(path)


# -- the wire ---------------------------------------------------------------------------------
def test_a_recipe_packs_and_unpacks_every_field_type_big_endian():
    types = ("BOOL", "UINT8", "UINT32", "INT32", "UINT64", "DOUBLE", "VECTOR3D", "VECTOR6D", "VECTOR6INT32", "VECTOR6UINT32")
    names = tuple(f"v{i}" for i in range(len(types)))
    values = {"v0": True, "v1": 200, "v2": 2**32 - 1, "v3": -5, "v4": 2**63, "v5": 0.3, "v6": (1.0, -2.0, 3.5),
              "v7": (0.1, 0.2, 0.3, 0.4, 0.5, 0.6), "v8": (-1, 2, -3, 4, -5, 6), "v9": (1, 2, 3, 4, 5, 6)}
    recipe = rtde.Recipe(3, names, types)
    data = recipe.pack(values)
    size, kind = struct.unpack(">HB", data[:3])
    assert size == len(data) and kind == ord("U") and data[3] == 3
    assert data[4:6] == b"\x01\xc8" and data[6:10] == b"\xff\xff\xff\xff"  # big-endian, as the controller's
    assert recipe.unpack(data[3:]) == {**values, "v6": (1.0, -2.0, 3.5)}
    with pytest.raises(rtde.RtdeError, match="recipe 4, expected 3"):
        recipe.unpack(bytes([4]) + data[4:])
    with pytest.raises(rtde.RtdeError, match="bytes of values"):
        recipe.unpack(data[3:-1])


def test_packages_are_cut_out_of_a_stream_however_it_arrives_and_a_header_shorter_than_itself_is_refused():
    stream = rtde.package(ord("V"), b"\x00\x02") + rtde.package(ord("S")) + rtde.text_message("hello", "x", 3)
    reader = rtde.PackageReader()
    got = [p for i in range(len(stream)) for p in reader.feed(stream[i:i + 1])]  # a byte at a time
    assert [k for k, _ in got] == [ord("V"), ord("S"), ord("M")]
    assert got[0][1] == b"\x00\x02" and got[2][1] == b"\x05hello\x01x\x03"
    with pytest.raises(rtde.RtdeError, match="less than the header"):
        rtde.PackageReader().feed(b"\x00\x02U")


def test_the_controllers_variables_and_registers_have_their_types_and_others_are_not_found():
    assert rtde.output_type("actual_q") == "VECTOR6D" and rtde.output_type("safety_status_bits") == "UINT32"
    assert rtde.output_type("output_int_register_47") == "INT32" and rtde.output_type("input_double_register_3") == "DOUBLE"
    assert rtde.output_type("output_int_register_48") == rtde.NOT_FOUND
    assert rtde.input_type("output_int_register_2") == rtde.NOT_FOUND  # a client writes inputs only
    assert rtde.input_type("speed_slider_fraction") == "DOUBLE" and rtde.input_type("input_bit_register_127") == "BOOL"
    assert rtde.names_of(b"timestamp,actual_q,") == ["timestamp", "actual_q"]  # ur-rtde ends its lists with a comma


def test_a_recipe_whose_types_are_not_the_documented_ones_is_refused():
    """A controller that answers a recipe with other types (``actual_q`` as one DOUBLE) would have its packages read
    as what they are not: the recipe is refused at setup, one line naming the field."""
    from cellsim.bridges.ur import UrLink

    names = ["timestamp", "actual_q"]
    good = UrLink._recipe(bytes([1]) + b"DOUBLE,VECTOR6D", names, "output")
    assert good.types == ("DOUBLE", "VECTOR6D")
    with pytest.raises(rtde.RtdeError, match=r"actual_q DOUBLE \(expected VECTOR6D\)"):
        UrLink._recipe(bytes([1]) + b"DOUBLE,DOUBLE", names, "output")


# -- the program's registers ------------------------------------------------------------------
@pytest.fixture(scope="module")
def program(tmp_path_factory):
    return load_bridge(ur_config(tmp_path_factory.mktemp("ur"), 30004)).programs["robot"]


def state(program, **changes) -> dict:
    r = program.registers
    values = {"timestamp": 1.0, "actual_q": (0.1, -1.0, 1.2, -1.5, -1.6, 0.0), "actual_qd": (0.0,) * 6,
              "robot_mode": rtde.ROBOT_RUNNING, "safety_mode": rtde.SAFETY_NORMAL, "runtime_state": 2,
              "safety_status_bits": 1, "speed_scaling": 1.0, "target_speed_fraction": 1.0,
              f"output_int_register_{r.safety_mode}": 2, f"output_int_register_{r.activity}": 2,
              f"output_int_register_{r.reached_pose}": 0}
    values.update(changes)
    return values


def test_the_programs_reported_mode_counts_only_while_the_controller_itself_is_not_stopped(program):
    r = program.registers
    assert program.sample(state(program)) == {
        "q0": 0.1, "q1": -1.0, "q2": 1.2, "q3": -1.5, "q4": -1.6, "q5": 0.0,
        "safety_mode": "ssmon", "activity": "welding", "reached_pose": "moving"}
    for code in (3, 4, 5, 6, 7, 8, 9, 12, 13):  # any of the controller's safety stops: stopped, whatever the program says
        assert program.sample(state(program, safety_mode=code))["safety_mode"] == "stopped"
    assert program.sample(state(program, robot_mode=5))["safety_mode"] == "stopped"  # powered, brakes on: not running
    for runtime in (0, 1, 3, 4, 5):  # the program stopped or paused: its registers are stale, nothing obeys the twin
        assert program.sample(state(program, runtime_state=runtime))["safety_mode"] == "stopped"
    assert program.sample(state(program, safety_mode=rtde.SAFETY_REDUCED))["safety_mode"] == "ssmon"
    for register, code in ((r.safety_mode, 7), (r.activity, -1), (r.reached_pose, 99)):
        with pytest.raises(OutOfRange):
            program.sample(state(program, **{f"output_int_register_{register}": code}))
    # the controller's own codes outside the lists it documents: the sample is refused (range), never "stopped"
    for field, code in (("safety_mode", 0), ("safety_mode", 99), ("robot_mode", 42), ("runtime_state", 77)):
        with pytest.raises(OutOfRange):
            program.sample(state(program, **{field: code}))
    # not running yet moving (braking after a protective stop, jogged, backdriven), or its safety mode undefined:
    # unknown, the dangerous case, never stopped
    moving = [0.0, 0.0, 0.5, 0.0, 0.0, 0.0]
    assert program.sample(state(program, safety_mode=3, actual_qd=moving))["safety_mode"] == "unknown"
    assert program.sample(state(program, runtime_state=1, actual_qd=moving))["safety_mode"] == "unknown"
    assert program.sample(state(program, robot_mode=6, actual_qd=moving))["safety_mode"] == "unknown"
    assert program.sample(state(program, safety_mode=11))["safety_mode"] == "unknown"
    assert program.sample(state(program, safety_mode=3, actual_qd=[0.005] * 6))["safety_mode"] == "stopped"


def test_a_command_goes_out_as_the_slider_at_its_modes_cap_and_codes_the_program_reads_back(program):
    r = program.registers
    values = program.input_values({"safety_mode_request": "ssmon", "activity": "welding", "target_pose": 2.0,
                                   "speed_limit": 0.5}, 7)
    assert values == {"speed_slider_mask": 1, "speed_slider_fraction": 0.5, f"input_int_register_{r.safety_mode_request}": 2,
                      f"input_int_register_{r.activity_request}": 2, f"input_int_register_{r.target_pose}": 2,
                      f"input_int_register_{r.heartbeat}": 7}
    caps = {"normal": 1.0, "hguid": 0.25, "ssmon": 0.5, "pflim": 0.25, "srmst": 0.0, "stopped": 0.0}  # welding_cell.yaml's
    for mode in MODES:
        for activity in ("idle", "exchWrkp", "welding", "off"):
            for target in (-1.0, 0.0, 2.0):
                # the SSM's limit as the robot sends it: the ssmon cap when no ssm module drives it
                command = {"safety_mode_request": mode, "activity": activity, "target_pose": target, "speed_limit": 0.5}
                values = program.input_values(command, 1)
                assert values["speed_slider_fraction"] == caps[mode]
                assert program.command(values) == (command, caps[mode])
    # in ssmon the slider follows the SSM monitor's limit below the cap; a limit with no value is a stop
    for limit, fraction in ((0.2, 0.2), (0.0, 0.0), (0.9, 0.5), (None, 0.0), (float("nan"), 0.0)):
        command = {"safety_mode_request": "ssmon", "activity": "welding", "target_pose": 2.0, "speed_limit": limit}
        assert program.input_values(command, 1)["speed_slider_fraction"] == fraction, limit
    # outside ssmon the SSM's limit is not in force (as in the robot kind): the mode's cap
    assert program.input_values({"safety_mode_request": "pflim", "speed_limit": 0.0}, 1)["speed_slider_fraction"] == 0.25
    # the kind's safe command: slider 0, stop, hold
    safe = program.input_values({"safety_mode_request": "stopped", "activity": "idle", "target_pose": -1.0,
                                 "speed_limit": 0.0}, 8)
    assert safe["speed_slider_fraction"] == 0.0 and safe[f"input_int_register_{r.safety_mode_request}"] == 5
    # a code the program cannot read is the stop
    assert program.command({f"input_int_register_{r.safety_mode_request}": 42})[0]["safety_mode_request"] == "stopped"
    # the twin not commanding (model, shadow): no request, the slider left alone, the heartbeat still counting
    released = program.input_values(None, 9)
    assert released["speed_slider_mask"] == 0 and released[f"input_int_register_{r.heartbeat}"] == 9
    assert {released[f"input_int_register_{n}"] for n in (r.safety_mode_request, r.activity_request, r.target_pose)} == {-1}
    assert program.command(released)[0] is None


@pytest.mark.parametrize("extra, key", [
    ("      registers: {safety_mode_request: 18, activity_request: 18}\n", "robots.robot.rtde.registers.safety_mode_request"),
    ("      registers: {heartbeat: 48}\n", "robots.robot.rtde.registers.heartbeat"),
    ("      port: 0\n", "robots.robot.rtde.port"),
    # (the audit's: a name with an empty part raised UnicodeError in the RTDE thread, which died, dialling no more)
    ("      host: 192.168.10..20\n", "robots.robot.rtde.host"),
    ("      host: ''\n", "robots.robot.rtde.host"),
])
def test_a_bad_rtde_setting_is_one_error_naming_its_key(tmp_path, extra, key):
    path = tmp_path / "bridge.yaml"
    path.write_text(e2e_only_text() + "    rtde:\n" + extra)
    with pytest.raises(ConfigError) as error:
        load_bridge(path)
    assert error.value.key == key, str(error.value)


# -- the daemon's link to a controller ----------------------------------------------------------
class Controller:
    """An emulated controller (the server the emulator runs) on a free loopback port, fed by the test."""

    def __init__(self, program, takes_slider: bool = True):
        self.program = program
        self.inputs: queue.Queue = queue.Queue()
        self.slider = 1.0
        self.takes_slider = takes_slider
        self.server = RtdeServer("127.0.0.1", 0, on_inputs=self._take)
        self.port = self.server.address[1]
        self.t = 0.0

    def _take(self, values: dict) -> None:
        """The daemon's inputs: the slider taken as a controller does (unless told to ignore it), and queued."""
        if self.takes_slider and values.get("speed_slider_mask", 0) & 1:
            self.slider = values["speed_slider_fraction"]
        self.inputs.put(values)

    def publish(self, fault=None, **fields) -> None:
        self.t += 0.002
        sample = {**{f"q{i}": 0.1 * i for i in range(6)}, "safety_mode": "normal", "activity": "welding",
                  "reached_pose": "home", **fields}
        self.server.publish(self.program.state(sample, [0.0] * 6, self.t, self.slider), fault)

    def inputs_until(self, condition, timeout: float = 5.0) -> dict:
        deadline = time.monotonic() + timeout
        while True:
            values = self.inputs.get(timeout=max(0.01, deadline - time.monotonic()))
            if condition(values):
                return values


class Twin:
    """What the twin's side hears on the daemon's keys, and how it commands."""

    def __init__(self, session):
        self.samples: queue.Queue = queue.Queue()
        self.session = session
        self.subscriber = session.declare_subscriber(
            "cellsim/welding_cell/physical/robot", lambda s: self.samples.put(json.loads(s.payload.to_bytes())))

    def next_sample(self, condition=lambda m: True, timeout: float = 5.0) -> dict:
        deadline = time.monotonic() + timeout
        while True:
            message = self.samples.get(timeout=max(0.01, deadline - time.monotonic()))
            if condition(message):
                return message


def connected(link, controller, timeout: float = 10.0) -> None:
    """Wait until the daemon's link has dialled the controller and the controller has it as a client."""
    deadline = time.monotonic() + timeout
    while not (link.connected and controller.server.clients):
        assert time.monotonic() < deadline, "the daemon did not dial the controller"
        threading.Event().wait(0.01)


def run_daemon(bridge: Bridge):
    """The daemon's loop on a thread (as ``cellsim bridge`` runs it); returns its stop event."""
    from cellsim.bridges.daemon import run_bridge

    stop = threading.Event()
    thread = threading.Thread(target=run_bridge, args=(bridge, None, stop), daemon=True)
    thread.start()
    return stop, thread


@contextlib.contextmanager
def daemon_beside_controller(sessions, tmp_path, program, takes_slider: bool = True):
    """The daemon's loop running beside an emulated controller on a free loopback port, connected; yields
    (controller, bridge, the robot's link, what the twin hears); everything stopped after."""
    hub, twin_session = sessions
    controller = Controller(program, takes_slider)
    bridge = Bridge(load_bridge(ur_config(tmp_path, controller.port)), hub)
    twin = Twin(twin_session)
    stop, thread = run_daemon(bridge)
    link = bridge.robots["robot"]
    try:
        connected(link, controller)
        yield controller, bridge, link, twin
    finally:
        stop.set()
        thread.join(timeout=5)
        bridge.close()
        controller.server.close()
        twin.subscriber.undeclare()


class TwinSide:
    """The twin's side of a daemon commanding a controller: its command publisher and its liveliness token."""

    def __init__(self, session):
        self.session = session
        self.command = session.declare_publisher("cellsim/welding_cell/command/robot")
        self.token = session.liveliness().declare_token("cellsim/welding_cell/alive/twin")

    def lose(self) -> None:
        """The twin's liveliness goes (as when its process ends)."""
        self.token.undeclare()
        self.token = None


@contextlib.contextmanager
def daemon_commanded_by_twin(sessions, tmp_path, program):
    """The daemon's loop beside an emulated controller, the twin alive on its keys; yields (controller, bridge, the
    twin's side); everything stopped after."""
    hub, twin_session = sessions
    controller = Controller(program)
    bridge = Bridge(load_bridge(ur_config(tmp_path, controller.port)), hub)
    stop, thread = run_daemon(bridge)
    twin = TwinSide(twin_session)
    try:
        yield controller, bridge, twin
    finally:
        if twin.token is not None:
            twin.token.undeclare()
        stop.set()
        thread.join(timeout=5)
        bridge.close()
        controller.server.close()


def test_a_controllers_states_become_the_robots_samples_and_faults_fail_it_at_once(sessions, tmp_path, program):  # noqa: F811
    with daemon_beside_controller(sessions, tmp_path, program) as (controller, bridge, link, twin):
        for _ in range(5):
            controller.publish(safety_mode="ssmon")
        sample = twin.next_sample(lambda m: "fields" in m)
        assert sample["fields"]["safety_mode"] == "ssmon" and sample["fields"]["q3"] == pytest.approx(0.3)
        assert sample["fields"]["activity"] == "welding" and sample["fields"]["reached_pose"] == "home"
        # the controller in a protective stop: stopped, whatever the program reports
        controller.server.publish({**program.state({**{f"q{i}": 0.0 for i in range(6)}, "safety_mode": "normal",
                                                      "activity": "idle", "reached_pose": "home"}, [0.0] * 6,
                                                   controller.t + 0.002, 1.0), "safety_mode": 3})
        controller.t += 0.002
        assert twin.next_sample(lambda m: "fields" in m and m["fields"]["activity"] == "idle")["fields"]["safety_mode"] == "stopped"
        # a package one byte short: corrupt, at once
        controller.publish(fault="corrupt")
        assert twin.next_sample(lambda m: "failed" in m)["failed"] == "corrupt"


@pytest.mark.parametrize("takes", [True, False])
def test_a_controller_that_does_not_take_the_slider_reads_unknown_where_its_arm_is(sessions, tmp_path, program, takes):  # noqa: F811
    """The daemon, the twin's mode not heard, writes the safe command: the slider at 0. A controller that takes it
    reports its program's mode; one still at full speed fraction once the grace has passed does not take the
    twin's slider: its safety mode reads unknown (it may be faster than asked), its joints as they are."""
    from cellsim.bridges.ur import SLIDER_GRACE

    with daemon_beside_controller(sessions, tmp_path, program, takes_slider=takes) as (controller, bridge, link, twin):
        controller.inputs_until(lambda v: v["speed_slider_mask"] == 1 and v["speed_slider_fraction"] == 0.0)
        written = time.monotonic()
        modes = []
        deadline = written + 10.0
        while not (takes and time.monotonic() > written + 3 * SLIDER_GRACE and len(modes) > 20) and not (
                not takes and modes and modes[-1] == "unknown"):
            assert time.monotonic() < deadline, f"read {modes[-5:]}"
            controller.publish(safety_mode="ssmon")
            sample = twin.next_sample(lambda m: "fields" in m)
            modes.append(sample["fields"]["safety_mode"])
        if takes:
            assert set(modes) == {"ssmon"} and link.checker.slider_refused == 0
        else:
            assert sample["fields"]["q3"] == pytest.approx(0.3) and link.checker.slider_refused > 0


def test_the_slider_a_controller_may_show_is_the_last_it_had_time_to_take_or_any_written_since():
    """Writes at 0 (0.2) and 30 ms (0.8): within the grace nothing is judged; after it the 0.2 binds, and the 0.8
    too, which it may have taken already; once the 0.8 is as old, it alone. A slider falling at every write binds
    each value as it ages. A release (the program's own slider) expects nothing."""
    from cellsim.bridges.ur import SLIDER_GRACE, RtdeStateChecker

    checker = RtdeStateChecker(timeout=1.0)
    checker.wrote_slider(0.2, 10.0)
    checker.wrote_slider(0.8, 10.03)
    assert checker.slider_allowed(10.0 + SLIDER_GRACE / 2) is None
    assert checker.slider_allowed(10.0 + SLIDER_GRACE + 0.01) == 0.8
    checker.wrote_slider(0.1, 10.03 + SLIDER_GRACE)
    assert checker.slider_allowed(10.03 + SLIDER_GRACE + 0.001) == 0.8  # the 0.1 is too new to bind
    assert checker.slider_allowed(10.03 + 2 * SLIDER_GRACE + 0.001) == 0.1
    falling = RtdeStateChecker(timeout=1.0)
    for k in range(30):
        falling.wrote_slider(1.0 - 0.03 * k, 20.0 + 0.02 * k)
    now = 20.0 + 0.02 * 29
    newest_old = max(k for k in range(30) if 20.0 + 0.02 * k <= now - SLIDER_GRACE)
    assert falling.slider_allowed(now) == pytest.approx(1.0 - 0.03 * newest_old)
    falling.wrote_slider(None, now)
    assert falling.slider_allowed(now + 1.0) is None
    # (the audit's: only a package reaching the slider check trimmed them; a controller sending corrupt ones for an
    # hour kept 180,000) the writes are trimmed as they are made, to the grace's worth
    silent = RtdeStateChecker(timeout=1.0)
    for k in range(5000):
        silent.wrote_slider(0.5, 30.0 + 0.02 * k)
    assert len(silent._written) <= SLIDER_GRACE / 0.02 + 2
    assert silent.slider_allowed(30.0 + 0.02 * 4999) == 0.5


def test_a_frozen_or_lost_controller_goes_stale_and_is_dialled_again(sessions, tmp_path, program):  # noqa: F811
    with daemon_beside_controller(sessions, tmp_path, program) as (controller, bridge, link, twin):
        deadline = time.monotonic() + 10
        while True:  # good packages until the twin hears one (under load the first few may come before the daemon reads)
            controller.publish()
            try:
                twin.next_sample(lambda m: "fields" in m, timeout=0.05)
                break
            except queue.Empty:
                assert time.monotonic() < deadline, "the twin heard no sample of the controller's"
        for _ in range(5):
            controller.publish(fault="freeze")  # the same package again: its timestamp repeats, refused
        assert twin.next_sample(lambda m: "failed" in m)["failed"] == "timeout"  # then the watchdog
        assert link.checker.counts["repeated"] == 5
        # a register holding a code outside its list: range
        controller.publish(reached_pose="home")
        controller.server.publish({**program.state({**{f"q{i}": 0.0 for i in range(6)}, "safety_mode": "normal",
                                                      "activity": "idle", "reached_pose": "home"}, [0.0] * 6,
                                                   controller.t + 0.002, 1.0),
                                   f"output_int_register_{program.registers.safety_mode}": 17})
        controller.t += 0.002
        assert twin.next_sample(lambda m: m.get("failed") == "range")
        # the controller goes away and comes back on the same port: dialled again
        port = controller.port
        controller.server.close()
        wait = time.monotonic() + 10
        while link.connected:
            assert time.monotonic() < wait
            threading.Event().wait(0.01)
        controller.server = RtdeServer("127.0.0.1", port, on_inputs=controller.inputs.put)
        while not (link.connected and link.connections == 2):
            assert time.monotonic() < wait, "the daemon did not dial the controller again"
            threading.Event().wait(0.01)


def test_in_twin_mode_the_controller_gets_the_slider_and_registers_and_slider_0_when_the_twin_is_lost(sessions, tmp_path, program):  # noqa: F811
    r = program.registers
    with daemon_commanded_by_twin(sessions, tmp_path, program) as (controller, bridge, twin):
        mode = twin.session.declare_publisher("cellsim/welding_cell/twin/robot/twin_mode")
        command = twin.command
        deadline = time.monotonic() + 10
        while not bridge._twin_alive:  # its modes are taken only from a living twin (which republishes them)
            assert time.monotonic() < deadline
            threading.Event().wait(0.01)
        mode.put(json.dumps({"t": time.time(), "sim_time": 0.0, "value": "shadow"}))
        while bridge.twin_mode("robot") is not TwinMode.SHADOW or not bridge.robots["robot"].connected:
            assert time.monotonic() < deadline
            threading.Event().wait(0.01)
        # shadow: the program runs on its own (no request, the slider untouched), told the daemon is there (what was
        # written before the mode was heard, the safe command, may come first)
        first = controller.inputs_until(lambda v: v["speed_slider_mask"] == 0)
        second = controller.inputs_until(lambda v: True)
        for values in (first, second):
            assert values["speed_slider_mask"] == 0 and values[f"input_int_register_{r.safety_mode_request}"] == -1
        assert second[f"input_int_register_{r.heartbeat}"] > first[f"input_int_register_{r.heartbeat}"]
        mode.put(json.dumps({"t": time.time(), "sim_time": 0.1, "value": "twin"}))
        fields = {"safety_mode_request": "ssmon", "activity": "welding", "target_pose": 2.0, "speed_limit": 0.5}
        seq = 0
        heartbeats = []
        deadline = time.monotonic() + 10
        while True:  # the twin publishes its command on change and every COMMAND_HEARTBEAT
            seq += 1
            command.put(json.dumps({"t": time.time(), "seq": seq, "fields": fields}))
            try:
                values = controller.inputs_until(lambda v: v["speed_slider_fraction"] == 0.5, timeout=0.1)
                break
            except queue.Empty:
                assert time.monotonic() < deadline
        assert values[f"input_int_register_{r.safety_mode_request}"] == 2  # ssmon's code
        assert values[f"input_int_register_{r.target_pose}"] == 2
        heartbeats.append(values[f"input_int_register_{r.heartbeat}"])
        heartbeats.append(controller.inputs_until(lambda v: True)[f"input_int_register_{r.heartbeat}"])
        assert heartbeats[1] > heartbeats[0]  # it counts up with every command sent
        twin.lose()
        lost = time.monotonic()
        values = controller.inputs_until(lambda v: v["speed_slider_fraction"] == 0.0)
        assert time.monotonic() - lost < 1.0
        assert values[f"input_int_register_{r.safety_mode_request}"] == 5 and values[f"input_int_register_{r.target_pose}"] == -1


def _commanding(command, seqs, fields, controller, condition, deadline_s: float = 10.0) -> dict:
    """Publish the twin's command every 0.1 s, numbered by ``seqs``, until the controller's inputs meet
    ``condition``; those inputs."""
    deadline = time.monotonic() + deadline_s
    while True:
        command.put(json.dumps({"t": time.time(), "seq": next(seqs), "fields": fields}))
        try:
            return controller.inputs_until(condition, timeout=0.1)
        except queue.Empty:
            assert time.monotonic() < deadline


@pytest.mark.parametrize("lose", ["liveliness", "commands"])
def test_a_daemon_that_has_not_heard_the_twins_mode_holds_the_safe_command_and_each_loss_alone_stops_the_arm(
        sessions, tmp_path, program, lose):  # noqa: F811
    """A daemon (re)started while the twin may command the arm writes the safe command, never a release (-1, the
    program's own), until the twin is heard: a good command of the twin's (it commands only what it twins) counts as
    twin mode. Then the twin is lost one way at a time: its liveliness gone while its commands still come, or its
    commands stopped while it is alive: each alone sets the slider to 0 and asks for a stop."""
    r = program.registers
    safe = lambda v: v["speed_slider_mask"] == 1 and v["speed_slider_fraction"] == 0.0 and (  # noqa: E731
        v[f"input_int_register_{r.safety_mode_request}"] == 5)
    with daemon_commanded_by_twin(sessions, tmp_path, program) as (controller, bridge, twin):
        command = twin.command
        connected(bridge.robots["robot"], controller)
        for _ in range(3):  # nothing heard of the twin's mode: the safe command, each cycle
            assert safe(controller.inputs_until(lambda v: True))
        fields = {"safety_mode_request": "ssmon", "activity": "welding", "target_pose": 2.0, "speed_limit": 0.5}
        seqs = itertools.count(1)
        _commanding(command, seqs, fields, controller, lambda v: v["speed_slider_fraction"] == 0.5)
        assert bridge.twin_mode("robot") is TwinMode.TWIN
        if lose == "liveliness":
            twin.lose()
            lost = time.monotonic()
            _commanding(command, seqs, fields, controller, safe)  # good commands still come: liveliness alone
        else:
            lost = time.monotonic()
            controller.inputs_until(safe, timeout=5.0)  # alive, silent: the command watchdog alone
        assert time.monotonic() - lost < 0.5 + 0.5  # the command watchdog and a command cycle, with room


def test_a_twin_command_with_no_safety_mode_goes_out_as_the_kinds_safe_mode(sessions, tmp_path, program):  # noqa: F811
    """A risk model's null request, in twin mode, is the kind's safe mode (stopped, 5) on the controller, the rest of
    the command as the twin sent it: -1 would tell the program the twin does not command the robot, disarming its
    stop when the daemon is lost. The daemon decides it once, for every protocol it speaks."""
    r = program.registers
    with daemon_commanded_by_twin(sessions, tmp_path, program) as (controller, bridge, twin):
        connected(bridge.robots["robot"], controller)
        fields = {"safety_mode_request": None, "activity": "welding", "target_pose": 2.0, "speed_limit": 0.5}
        values = _commanding(twin.command, itertools.count(1), fields, controller,
                             lambda v: v[f"input_int_register_{r.target_pose}"] == 2)  # the twin's, not the safe hold
        assert values[f"input_int_register_{r.safety_mode_request}"] == 5 and values["speed_slider_fraction"] == 0.0


def test_a_client_that_asks_and_never_reads_is_dropped_and_never_blocks_the_emulated_cell():
    """The audit's case: a reply was sent with a blocking sendall under the lock the emulated cell's publish takes, so a
    client sending requests and reading none of its replies held the cell's publish until it went away. Replies are
    sent as packages are: one that does not fit drops the client."""
    import socket
    import threading
    import time

    server = RtdeServer("127.0.0.1", 0)
    sock = socket.create_connection(server.address, timeout=5)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        reader = rtde.PackageReader()
        for kind, payload in ((rtde.SETUP_OUTPUTS, struct.pack(">d", 500.0) + b"timestamp"), (rtde.START, b"")):
            sock.sendall(rtde.package(kind, payload))
            while not any(got == kind for got, _ in reader.feed(sock.recv(4096))):
                pass  # (its reply: the server serves this client, streaming)
        assert server.clients == 1
        flood = rtde.package(rtde.GET_URCONTROL_VERSION) * 20000  # 60 kB of requests: 380 kB of replies, never read
        sock.setblocking(False)
        deadline = time.monotonic() + 20.0
        while server.clients and time.monotonic() < deadline:  # until the server drops the client (or the deadline)
            try:
                sock.send(flood)
            except BlockingIOError:
                select.select([], [sock], [], 0.05)  # (wait for room to send more, with a deadline)
            except OSError:
                break  # reset: dropped
        published = threading.Event()
        threading.Thread(target=lambda: (server.publish({"timestamp": 1.0}), published.set()), daemon=True).start()
        assert published.wait(10.0)  # the cell's publish was not held
        assert server.clients == 0
    finally:
        sock.close()
        server.close()


def test_the_emulated_controller_refuses_what_rtde_has_no_place_for():
    import socket

    inputs: list = []
    server = RtdeServer("127.0.0.1", 0, on_inputs=inputs.append)
    try:
        with socket.create_connection(server.address, timeout=5) as sock:
            reader = rtde.PackageReader()

            def ask(kind: int, payload: bytes = b"") -> bytes:
                sock.sendall(rtde.package(kind, payload))
                while True:
                    for got, body in reader.feed(sock.recv(4096)):
                        if got == kind:
                            return body

            assert ask(rtde.REQUEST_PROTOCOL_VERSION, b"\x00\x02") == b"\x01"
            assert struct.unpack(">IIII", ask(rtde.GET_URCONTROL_VERSION))[0] == 5
            reply = ask(rtde.SETUP_OUTPUTS, struct.pack(">d", 500.0) + b"timestamp,no_such_thing")
            assert reply[0] == 0 and rtde.names_of(reply[1:]) == ["DOUBLE", "NOT_FOUND"]
            reply = ask(rtde.SETUP_INPUTS, b"speed_slider_mask,speed_slider_fraction")
            assert reply[0] == 1 and rtde.names_of(reply[1:]) == ["UINT32", "DOUBLE"]
            with socket.create_connection(server.address, timeout=5) as other:  # another client: in use
                other.sendall(rtde.package(rtde.SETUP_INPUTS, b"speed_slider_fraction"))
                answer = rtde.PackageReader()
                got = []
                while not got:
                    got = answer.feed(other.recv(4096))
                assert got[0][1][0] == 0 and rtde.names_of(got[0][1][1:]) == ["IN_USE"]
            sock.sendall(rtde.package(rtde.DATA_PACKAGE, b"\x09" + bytes(12)))  # a recipe never set up
            said = b""
            while True:
                data = sock.recv(4096)
                if not data:
                    break
                said += data
            assert b"not set up" in said  # told why, then disconnected
    finally:
        server.close()
    assert inputs == []


@pytest.mark.parametrize("args, expected", [
    (["emulate", "scenarios/welding_cell.yaml", "--rtde", "70000"], "a port is a number from 1 to 65535"),
    (["emulate", "scenarios/welding_cell.yaml", "--rtde", "30004"], "names 0 robots over RTDE"),
    (["bridge", "bridges/welding_cell.yaml", "--rtde", "30004"], "names 0 robots over RTDE"),
    (["bridge", "bridges/welding_cell_ur_plc.yaml", "--rtde", "host:"], "expected [HOST:]PORT"),
    (["bridge", "bridges/welding_cell_ur_plc.yaml", "--rtde", "192.168.10..20:30004"], "is not a host name"),
    (["bridge", "bridges/welding_cell_ur_plc.yaml", "--opcua", "opc.tcp://127.0.0.1:48x0"], "its port is not a number"),
])
def test_bad_rtde_arguments_are_one_line_exit_2(args, expected):
    import subprocess
    import sys

    from conftest import ROOT

    proc = subprocess.run([sys.executable, "-m", "cellsim", *args], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 2, proc.stderr
    assert expected in proc.stderr.strip().splitlines()[-1], proc.stderr  # one line says it (after argparse's usage)


def test_a_controller_gone_silent_without_closing_is_dialled_again(sessions, tmp_path, program):  # noqa: F811
    """A controller powered off or cut off sends no FIN: the daemon's read times out, it closes and dials again."""
    with daemon_beside_controller(sessions, tmp_path, program) as (controller, bridge, link, twin):
        deadline = time.monotonic() + 10
        controller.publish()  # then nothing more, the connection left open
        while link.connections < 2:  # RECEIVE_TIMEOUT (1 s), then reconnect_after (0.2 s)
            assert time.monotonic() < deadline, "the silent controller was not dialled again"
            threading.Event().wait(0.01)


def test_the_emulated_program_takes_a_command_only_when_the_heartbeat_moved_and_none_when_released(program):
    from cellsim.bridges.devices import EmulatedController

    class Source:
        def __init__(self):
            self.got = []

        def deliver(self, payload):
            self.got.append(json.loads(payload)["fields"])

    emulated = EmulatedController("127.0.0.1", 0, program, 500.0)
    try:
        emulated.source = source = Source()
        command = {"safety_mode_request": "pflim", "activity": "idle", "target_pose": 0.0, "speed_limit": 0.5}
        emulated._on_inputs(program.input_values(command, 1))
        emulated._on_inputs(program.input_values(command, 1))  # the same heartbeat: the daemon stalled, not taken
        emulated._on_inputs(program.input_values(None, 2))  # released: no command at all
        emulated._on_inputs(program.input_values(command, 3))
        assert source.got == [command, command]
        assert emulated.slider == 0.25  # pflim's cap over normal's
        emulated._on_inputs({"speed_slider_mask": 1})  # a slider without its fraction: ignored, nothing raised
        assert emulated.slider == 0.25
    finally:
        emulated.server.close()


def test_the_emulated_controller_takes_clients_only_once_its_arm_has_a_state(program):
    """ur-rtde's receiver gives up for good after 2.5 s without a package: an emulator still building its cell
    refuses connections (its port already bound) until the arm's first state, then streams every cycle."""
    import socket

    from cellsim.bridges.devices import EmulatedController

    emulated = EmulatedController("127.0.0.1", 0, program, 500.0)
    try:
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection(emulated.server.address, timeout=5).close()
        sample = {**{f"q{i}": 0.0 for i in range(6)}, "safety_mode": "normal", "activity": "welding", "reached_pose": "home"}
        emulated.server.publish(program.state(sample, [0.0] * 6, 0.002, 1.0))
        socket.create_connection(emulated.server.address, timeout=5).close()
    finally:
        emulated.server.close()


@pytest.mark.parametrize("flag", ["--rtde", "--opcua"])
def test_emulate_on_a_port_already_taken_is_one_line_naming_it_exit_2_and_writes_nothing(tmp_path, flag, cell_keys):
    import socket
    import subprocess
    import sys

    import zenoh

    from cellsim.live.session import session_config
    from conftest import ROOT

    port = free_port()
    twin = zenoh.open(session_config(role="twin", insecure=True, listen=[f"tcp/127.0.0.1:{port}"], listen_by_default=True))
    try:
        with socket.socket() as taken:
            taken.bind(("127.0.0.1", 0))
            taken.listen()
            busy = taken.getsockname()[1]
            other = "--opcua" if flag == "--rtde" else "--rtde"  # on a free port, not the configuration's (30004)
            proc = subprocess.run([sys.executable, "-m", "cellsim", "emulate", "scenarios/welding_cell.yaml", flag, str(busy),
                                   other, str(free_port()),
                                   "--bridge", "bridges/welding_cell_ur_plc.yaml", "--keys", str(cell_keys),
                                   "--insecure", "--connect", f"tcp/127.0.0.1:{port}", "--out", str(tmp_path / "emulator"),
                                   "--duration", "1"], capture_output=True, text=True, timeout=120, cwd=ROOT)
    finally:
        twin.close()
    assert proc.returncode == 2, proc.stderr
    said = proc.stderr.strip().splitlines()[-1]
    assert said.startswith("cellsim: error: cannot serve the devices' protocols") and str(busy) in said, proc.stderr
    assert not (tmp_path / "emulator").exists()  # refused before anything is recorded


def test_a_twin_mode_heard_while_the_twin_is_lost_is_refused(sessions, tmp_path, program):  # noqa: F811
    """A mode message while the twin's liveliness is gone (stale, or forged with a leaked key) could release a robot
    the daemon holds safe: it is refused, counted, and the mode stays as it was; once the twin is alive, its modes
    are taken."""
    hub, _ = sessions
    bridge = Bridge(load_bridge(ur_config(tmp_path, 9)), hub)  # never dialled: the daemon's loop is not run
    try:
        shadow = json.dumps({"t": time.time(), "sim_time": 0.0, "value": "shadow"}).encode()
        bridge.take(("alive", None, False, 0.0))
        refused = bridge.refused_messages
        bridge.take(("mode", "robot", shadow, 0.0))
        assert bridge.twin_mode("robot") is None and bridge.refused_messages == refused + 1
        bridge.take(("alive", None, True, 0.0))
        bridge.take(("mode", "robot", shadow, 0.0))
        assert bridge.twin_mode("robot") is TwinMode.SHADOW
        bridge.take(("alive", None, False, 0.0))  # lost again: a later mode does not change what was heard
        bridge.take(("mode", "robot", json.dumps({"t": time.time(), "sim_time": 1.0, "value": "model"}).encode(), 0.0))
        assert bridge.twin_mode("robot") is TwinMode.SHADOW
    finally:
        bridge.close()
