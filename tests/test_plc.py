"""A PLC over OPC UA: the node coding, the configuration, and the daemon's link to the emulated PLC."""

from __future__ import annotations

import json
import math
import queue
import threading
import time

import pytest

from cellsim.bridges.config import load_bridge
from cellsim.bridges.daemon import Bridge
from cellsim.bridges.opcua import NodeValueError, from_node, to_node
from cellsim.live.pki import opcua_files
from cellsim.bridges.plc_server import EmulatedPlc
from cellsim.channels import BOOL, enum_type, number_type
from cellsim.config.typed_yaml import ConfigError
from cellsim.vocabulary import SafetyMode, TwinMode

from live_processes import free_port
from test_bridge import e2e_only_text, sessions  # noqa: F401 - the fixture
from test_ur import run_daemon

PLC = """plc:
  endpoint: opc.tcp://127.0.0.1:{port}
  security: {security}
  heartbeat: ns=2;s=PLC.Heartbeat
  command_heartbeat: ns=2;s=Bridge.Heartbeat
  entities:
    light_barrier:
      fields: {{broken: ns=2;s=LightCurtain.Broken}}
    welder:
      fields: {{safety_mode: ns=2;s=Welder.SafetyMode, activity: ns=2;s=Welder.Activity}}
      commands: {{safety_mode_request: ns=2;s=Welder.SafetyModeRequest, activity_request: ns=2;s=Welder.ActivityRequest,
                 command: ns=2;s=Welder.Weld}}
"""


def plc_config(tmp_path, port: int, security: str = "sign_encrypt", extra: str = "") -> str:
    """The E2E-only welding bridge with the light curtain and the welder wired to a PLC on loopback ``port``."""
    text = e2e_only_text()
    head, _, rest = text.partition("devices:\n")
    devices, _, tail = rest.partition("\ncommands:\n")
    kept = "devices:\n" + devices.split("  light_barrier:")[0] + "  range_detector:" + devices.split("  range_detector:")[1].split("  welder:")[0]
    robots = tail[tail.index("robots:"):] if "robots:" in tail else ""
    between = tail[:tail.index("robots:")] if robots else tail
    freshness = between[between.index("freshness_tick"):] if "freshness_tick" in between else ""
    path = tmp_path / "bridge_plc.yaml"
    path.write_text(head + kept + "\n" + freshness + robots + PLC.format(port=port, security=security) + extra)
    return str(path)


# -- the coding ------------------------------------------------------------------------------
def test_a_field_sits_in_its_node_as_its_code_a_boolean_or_a_double_and_a_value_it_cannot_take_is_refused():
    modes = enum_type(SafetyMode)
    assert to_node(modes, "stopped") == 5 and from_node(modes, 5) == "stopped"
    assert to_node(modes, None) == -1 and from_node(modes, -1, nullable=True) is None
    assert to_node(BOOL, True) is True and from_node(BOOL, False) is False
    number = number_type("m")
    assert to_node(number, 1.5) == 1.5 and math.isnan(to_node(number, None)) and from_node(number, math.nan, nullable=True) is None
    for ctype, value in ((modes, 7), (modes, -1), (modes, 2.0), (modes, True), (BOOL, 1), (number, math.inf),
                         (number, math.nan), (number, "1")):
        with pytest.raises(NodeValueError):
            from_node(ctype, value)


@pytest.mark.parametrize("change, key", [
    (("security: sign_encrypt", "security: none"), "plc.security"),
    (("heartbeat: ns=2;s=PLC.Heartbeat", "heartbeat: ns=2;q=oops"), "plc.heartbeat"),
    (("command_heartbeat: ns=2;s=Bridge.Heartbeat", "command_heartbeat: ns=2;s=PLC.Heartbeat"), "plc.command_heartbeat"),
    (("fields: {broken: ns=2;s=LightCurtain.Broken}", "fields: {}"), "plc.entities.light_barrier.fields"),
    (("command: ns=2;s=Welder.Weld", "weld: ns=2;s=Welder.Weld"), "plc.entities.welder.commands.weld"),
    (("endpoint: opc.tcp://127.0.0.1:4840", "endpoint: http://127.0.0.1:4840"), "plc.endpoint"),
    # (the audit's: asyncua refused these only when dialling, and the daemon dialled again forever)
    (("endpoint: opc.tcp://127.0.0.1:4840", "endpoint: opc.tcp://127.0.0.1:48x0"), "plc.endpoint"),
    (("endpoint: opc.tcp://127.0.0.1:4840", "endpoint: opc.tcp://plc..cell:4840"), "plc.endpoint"),
    (("endpoint: opc.tcp://127.0.0.1:4840", "endpoint: opc.tcp://127.0.0.1:70000"), "plc.endpoint"),
    (("  heartbeat: ns=2;s=PLC.Heartbeat", "  watchdog: 0.01\n  heartbeat: ns=2;s=PLC.Heartbeat"), "plc.watchdog"),
    (("  heartbeat: ns=2;s=PLC.Heartbeat", "  command_cycle_time: 0.3\n  heartbeat: ns=2;s=PLC.Heartbeat"),
     "plc.command_cycle_time"),
])
def test_a_bad_plc_setting_is_one_error_naming_its_key(tmp_path, change, key):
    path = tmp_path / "bridge.yaml"
    text = open(plc_config(tmp_path, 4840)).read()
    assert change[0] in text
    path.write_text(text.replace(change[0], change[1]))
    with pytest.raises(ConfigError) as error:
        load_bridge(path)
    assert error.value.key == key, str(error.value)


def test_an_entity_wired_to_the_plc_and_on_the_bus_is_refused(tmp_path):
    text = e2e_only_text() + PLC.format(port=4840, security="sign_encrypt")
    path = tmp_path / "bridge.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="one physical twin"):
        load_bridge(path)


# -- the daemon and the emulated PLC ----------------------------------------------------------
@pytest.fixture
def certificates(tmp_path):
    folder = tmp_path / "keys"
    bridge, plc = opcua_files(folder, "bridge"), opcua_files(folder, "plc")
    return (*bridge, plc[0]), (*plc, bridge[0])


class Source:
    """Stands for the emulated entity's command source: what the PLC's program took."""

    def __init__(self):
        self.commands: queue.Queue = queue.Queue()

    def deliver(self, payload: bytes) -> None:
        self.commands.put(json.loads(payload)["fields"])


def start(tmp_path, hub, certificates, security="sign_encrypt"):
    port = free_port()
    loaded = load_bridge(plc_config(tmp_path, port, security))
    plc = EmulatedPlc(loaded.config.plc, loaded.samples, loaded.commands, loaded.safe,
                      certificates=certificates[1] if security != "none" else None)
    bridge = Bridge(loaded, hub, plc_certificates=certificates[0] if security != "none" else None)
    return plc, bridge


def samples_of(session, entity: str) -> queue.Queue:
    got: queue.Queue = queue.Queue()
    session.declare_subscriber(f"cellsim/welding_cell/physical/{entity}", lambda s: got.put(json.loads(s.payload.to_bytes())))
    return got


def next_message(messages: queue.Queue, condition, timeout: float = 10.0) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        message = messages.get(timeout=max(0.01, deadline - time.monotonic()))
        if condition(message):
            return message


def test_the_plcs_nodes_become_samples_and_a_bad_status_or_a_frozen_scan_fails_them(sessions, tmp_path, certificates):  # noqa: F811
    hub, twin = sessions
    curtain, welder = samples_of(twin, "light_barrier"), samples_of(twin, "welder")
    plc, bridge = start(tmp_path, hub, certificates)
    stop, thread = run_daemon(bridge)
    try:
        plc.publish("light_barrier", {"broken": True}, None)
        plc.publish("welder", {"safety_mode": "ssmon", "activity": "welding"}, None)
        assert next_message(curtain, lambda m: "fields" in m)["fields"] == {"broken": True}
        assert next_message(welder, lambda m: "fields" in m)["fields"] == {"safety_mode": "ssmon", "activity": "welding"}
        assert bridge.plc.connected and bridge.plc.connections == 1
        plc.publish("light_barrier", {"broken": False}, None)
        assert next_message(curtain, lambda m: m.get("fields") == {"broken": False})
        # the curtain's input fails in the PLC: its nodes carry a bad status, the curtain is corrupt at once
        plc.publish("light_barrier", {"broken": False}, "bad_status")
        assert next_message(curtain, lambda m: "failed" in m)["failed"] == "corrupt"
        plc.publish("light_barrier", {"broken": False}, None)
        next_message(curtain, lambda m: "fields" in m)  # and trusted again once good
        # the PLC's scan freezes: its heartbeat stands still, every entity of it goes stale within the watchdog
        plc.publish("welder", {"safety_mode": "ssmon", "activity": "welding"}, "freeze")
        frozen = time.monotonic()
        assert next_message(welder, lambda m: "failed" in m)["failed"] == "timeout"
        assert next_message(curtain, lambda m: "failed" in m)["failed"] == "timeout"
        assert time.monotonic() - frozen < 0.2 + 0.2  # the watchdog, and the daemon's cycle and a publish
    finally:
        stop.set()
        thread.join(timeout=10)
        bridge.close()
        plc.close()


def test_every_value_the_plc_takes_between_two_publishes_is_a_sample_in_the_order_the_plc_took_them(sessions, tmp_path, certificates):  # noqa: F811
    """A publishing interval (here 0.25 s) far longer than the changes: the curtain broken and clear twice, the welder's
    two nodes changed twice, each held two PLC scans. Every value reaches the twin (the nodes are queued, not only
    their last value), and in the PLC's order across nodes: the welder's first full state is a sample."""
    hub, twin = sessions
    curtain, welder = samples_of(twin, "light_barrier"), samples_of(twin, "welder")
    port = free_port()
    loaded = load_bridge(plc_config(tmp_path, port, "sign_encrypt", "  publishing_interval: 0.25\n  watchdog: 1.0\n"))
    plc = EmulatedPlc(loaded.config.plc, loaded.samples, loaded.commands, loaded.safe, certificates=certificates[1])
    bridge = Bridge(loaded, hub, plc_certificates=certificates[0])
    stop, thread = run_daemon(bridge)

    def two_scans() -> None:
        deadline, start = time.monotonic() + 5.0, plc.scans
        while plc.scans < start + 2:
            assert time.monotonic() < deadline, "the emulated PLC stopped scanning"
            time.sleep(0.0005)

    def changes(messages: queue.Queue, start: dict, count: int) -> list[dict]:
        """The samples' fields after ``start``, each change once, ``count`` of them (a scan repeats the current one)."""
        got = [start]
        while len(got) <= count:
            message = next_message(messages, lambda m: "fields" in m)
            if message["fields"] != got[-1]:
                got.append(message["fields"])
        return got[1:]

    try:
        plc.publish("light_barrier", {"broken": False}, None)
        plc.publish("welder", {"safety_mode": "normal", "activity": "idle"}, None)
        next_message(curtain, lambda m: m.get("fields") == {"broken": False})
        next_message(welder, lambda m: m.get("fields") == {"safety_mode": "normal", "activity": "idle"})
        for broken in (True, False, True, False):
            plc.publish("light_barrier", {"broken": broken}, None)
            two_scans()
        for mode, activity in (("ssmon", "welding"), ("normal", "idle")):
            plc.publish("welder", {"safety_mode": mode, "activity": activity}, None)
            two_scans()
        assert [f["broken"] for f in changes(curtain, {"broken": False}, 4)] == [True, False, True, False]
        # the PLC writes a scan's nodes one by one: the welder passes through each node's change, in the PLC's order
        got = changes(welder, {"safety_mode": "normal", "activity": "idle"}, 4)
        assert [(f["safety_mode"], f["activity"]) for f in got] == [
            ("ssmon", "idle"), ("ssmon", "welding"), ("normal", "welding"), ("normal", "idle")]
    finally:
        stop.set()
        thread.join(timeout=10)
        bridge.close()
        plc.close()


def test_in_twin_mode_the_welders_command_nodes_carry_the_twins_command_and_its_safe_one_when_lost(sessions, tmp_path, certificates):  # noqa: F811
    hub, twin = sessions
    plc, bridge = start(tmp_path, hub, certificates)
    source = Source()
    plc.sources["welder"] = source
    stop, thread = run_daemon(bridge)
    mode = twin.declare_publisher("cellsim/welding_cell/twin/welder/twin_mode")
    command = twin.declare_publisher("cellsim/welding_cell/command/welder")
    token = twin.liveliness().declare_token("cellsim/welding_cell/alive/twin")
    try:
        deadline = time.monotonic() + 10
        while not bridge.plc.connected or not bridge._twin_alive:  # modes are taken only from a living twin
            assert time.monotonic() < deadline
            threading.Event().wait(0.01)
        # the twin's mode not heard yet (the daemon may have started beside a commanding twin): the safe command
        safe = {"safety_mode_request": "stopped", "activity_request": "off", "command": 0.0}
        next_message(source.commands, lambda c: c == safe)
        # shadow: the welder's command nodes hold no value (released), the daemon's heartbeat counting
        mode.put(json.dumps({"t": time.time(), "sim_time": 0.0, "value": "shadow"}))
        request = "ns=2;s=Welder.SafetyModeRequest"
        while plc._commands.get(request) != -1 or not isinstance(plc._command_heartbeat, int):
            assert time.monotonic() < deadline, "the daemon never released the welder's command nodes"
            threading.Event().wait(0.01)

        def next_beat() -> None:
            beat = plc._command_heartbeat
            while plc._command_heartbeat == beat:
                assert time.monotonic() < deadline, "the daemon's heartbeat stopped in shadow mode"
                threading.Event().wait(0.01)

        next_beat()
        while not source.commands.empty():  # what the PLC took before the release
            source.commands.get()
        next_beat()
        assert source.commands.empty()  # released: the PLC's program runs the welder on its own
        mode.put(json.dumps({"t": time.time(), "sim_time": 0.1, "value": "twin"}))
        while bridge.twin_mode("welder") is not TwinMode.TWIN:
            assert time.monotonic() < deadline
            threading.Event().wait(0.01)
        fields = {"safety_mode_request": "normal", "activity_request": "welding", "command": 1.0}
        seq = 0
        while True:
            seq += 1
            command.put(json.dumps({"t": time.time(), "seq": seq, "fields": fields}))
            try:
                next_message(source.commands, lambda c: c == fields, timeout=0.1)
                break
            except queue.Empty:
                assert time.monotonic() < deadline, "the PLC never took the twin's command"
        token.undeclare()
        token = None
        lost = time.monotonic()
        # the welder kind's safe command: stopped, off, no weld
        next_message(source.commands, lambda c: c == {"safety_mode_request": "stopped", "activity_request": "off",
                                                       "command": 0.0})
        assert time.monotonic() - lost < 1.0
        assert bridge.plc.safe_writes > 0
    finally:
        if token is not None:
            token.undeclare()
        stop.set()
        thread.join(timeout=10)
        bridge.close()
        plc.close()


def test_a_client_with_another_certificate_is_refused_and_the_daemon_refuses_another_plc(tmp_path, certificates):
    import asyncio

    from asyncua import Client
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
    from asyncua.crypto.uacrypto import CertProperties

    port = free_port()
    loaded = load_bridge(plc_config(tmp_path, port))
    plc = EmulatedPlc(loaded.config.plc, loaded.samples, loaded.commands, loaded.safe, certificates=certificates[1])
    stranger = opcua_files(tmp_path / "other", "bridge")
    impostor = opcua_files(tmp_path / "other", "plc")[0]

    async def connect(certificate, key, server) -> str:
        client = Client(f"opc.tcp://127.0.0.1:{port}", timeout=5)
        client.application_uri = "urn:cellsim:bridge"
        await client.set_security(SecurityPolicyBasic256Sha256, CertProperties(str(certificate), "pem"),
                                  CertProperties(str(key), "pem"), server_certificate=CertProperties(str(server), "pem"))
        try:
            async with client:
                return str(await client.get_node("ns=2;s=PLC.Heartbeat").read_value())
        except Exception as e:  # noqa: BLE001 - what the refusal raises
            return f"refused: {type(e).__name__}"

    async def forged() -> str:
        """A client of no certificate on a channel without security (asyncua's own client would refuse the PLC's
        endpoints itself: this one takes any), writing the daemon's command heartbeat."""
        from asyncua import ua

        client = Client(f"opc.tcp://127.0.0.1:{port}", timeout=5)
        try:
            async with client:
                await client.get_node("ns=2;s=Bridge.Heartbeat").write_value(ua.Variant(7, ua.VariantType.Int32))
                return "wrote"
        except Exception as e:  # noqa: BLE001 - what the refusal raises
            return f"refused: {type(e).__name__}"

    try:
        own_certificate, own_key, plc_certificate = certificates[0]
        assert asyncio.run(connect(own_certificate, own_key, plc_certificate)).isdigit()  # the bridge's own: it reads
        # anyone else's: refused by the PLC for its certificate (not a timeout, which a slow server would give too)
        assert asyncio.run(connect(*stranger, plc_certificate)) == "refused: BadCertificateUntrusted"
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(Client, "find_endpoint", staticmethod(lambda endpoints, mode, policy: endpoints[0]))
            assert asyncio.run(forged()) == "refused: BadUserAccessDenied"  # no certificate, no session
    finally:
        plc.close()
    # the daemon, given the certificate of another PLC than the one serving: it never connects
    from cellsim.bridges.plc import PlcLink

    plc = EmulatedPlc(loaded.config.plc, loaded.samples, loaded.commands, loaded.safe, certificates=certificates[1])
    inbox: queue.Queue = queue.Queue()

    class Session:
        def declare_publisher(self, key):
            return type("P", (), {"put": lambda self, payload: None})()

    link = PlcLink("welding_cell", loaded.config.plc, Session(), loaded.samples, loaded.commands, loaded.safe, inbox,
                   certificates=(own_certificate, own_key, impostor))
    link.start()
    try:
        with pytest.raises(queue.Empty):
            inbox.get(timeout=2.0)  # nothing from a PLC it does not trust
        assert not link.connected
    finally:
        link.close()
        plc.close()


def test_a_restarted_plc_is_heard_at_once_and_a_bad_heartbeat_fails_every_entity(tmp_path):
    """The heartbeat: any change is a scan (a PLC restarting counts from 0 again, a counter wraps), a repeat is not;
    a heartbeat the PLC itself marks bad, or that is no integer, fails every entity of the PLC."""
    from cellsim.bridges.plc import HEARTBEAT

    published = []
    loaded, link = _unit_link(tmp_path, published)
    nodes = {name: node for name, node in loaded.config.plc.entities["light_barrier"].fields.items()}
    link.take(nodes["broken"].replace(" ", ""), False, True, 0.0)
    samples = lambda: [m for k, m in published if k.endswith("physical/light_barrier") and "fields" in m]  # noqa: E731
    for t, beat in enumerate((500, 501, 502, 0, 1), start=1):  # 502 -> 0: the PLC restarted
        link.take(HEARTBEAT, beat, True, 0.01 * t)
    assert len(samples()) == 5  # every scan heard, the restart's included
    link.take(HEARTBEAT, 1, True, 0.06)  # a repeat: the scan did not move
    assert len(samples()) == 5 and link.heartbeat.counts["repeated"] == 1
    link.take(HEARTBEAT, 2, False, 0.07)  # the PLC marks its own heartbeat bad
    failures = [m["failed"] for k, m in published if "failed" in m]
    assert failures.count("corrupt") == 2  # the curtain and the welder
    # while the scan is bad, the curtain's changes are kept but not trusted: no good sample until the scan moves good
    before = len(samples())
    for t, broken in enumerate((True, False, True, False), start=8):
        link.take(nodes["broken"].replace(" ", ""), broken, True, 0.01 * t)
    assert len(samples()) == before and link.entities["light_barrier"].trust.link.value == "corrupt"
    link.take(HEARTBEAT, 3, True, 0.13)  # the scan moves, good: the curtain's current value, trusted again
    assert samples()[-1]["fields"] == {"broken": False} and len(samples()) == before + 1


def test_after_a_reconnect_nothing_from_before_the_outage_is_published_as_a_fresh_sample(tmp_path):
    """The audit's case: the new connection's first heartbeat taken before the entity nodes' first values published
    the values from before the outage, stamped now, as a good sample. A new session forgets them: a scan publishes an
    entity again only once every one of its nodes was heard on the new connection."""
    from cellsim.bridges.plc import HEARTBEAT, NEW_SESSION

    published = []
    loaded, link = _unit_link(tmp_path, published)
    broken = loaded.config.plc.entities["light_barrier"].fields["broken"].replace(" ", "")
    samples = lambda: [m for k, m in published if k.endswith("physical/light_barrier") and "fields" in m]  # noqa: E731
    link.take(broken, False, True, 0.0)
    link.take(HEARTBEAT, 1, True, 0.01)
    assert samples()[-1]["fields"] == {"broken": False}
    link.take(NEW_SESSION, None, True, 1.0)  # the connection was lost and is made again
    link.take(HEARTBEAT, 2, True, 1.01)  # its heartbeat first: the curtain not heard yet on it
    assert len(samples()) == 1
    link.take(broken, True, True, 1.02)  # what the curtain is now: published at once, and with each scan
    link.take(HEARTBEAT, 3, True, 1.03)
    assert [m["fields"] for m in samples()[1:]] == [{"broken": True}, {"broken": True}]


def test_one_publishs_values_keep_each_nodes_order_and_interleave_by_their_stamps():
    """The OPC UA client's hand-over: values of one publish, listed node by node, reach the daemon sorted by source
    timestamp across nodes, while each node's own values keep the server's order whatever their stamps (a clock
    stepped back, a Bad value stamped by the server only, OPC UA's "no time")."""
    from datetime import datetime, timedelta, timezone
    from types import SimpleNamespace

    from cellsim.bridges.plc import PublishInOrder

    t0 = datetime(2026, 11, 28, 12, 0, tzinfo=timezone.utc)
    at = lambda ms: t0 + timedelta(milliseconds=ms)  # noqa: E731
    no_time = datetime(1601, 1, 1, tzinfo=timezone.utc)
    # (node, value, source stamp, server stamp) in the order the server lists them: node by node
    listed = [("A", 1, at(1), at(1)), ("A", 2, at(5), at(5)), ("A", 3, at(3), at(6)),  # A's clock stepped back
              ("B", "x", at(2), at(2)), ("B", "y", None, at(4)), ("B", "z", no_time, at(7))]
    delivered, scheduled = [], []
    order = PublishInOrder(delivered.append, SimpleNamespace(call_soon=scheduled.append))
    for node, value, source, server in listed:
        order.add(node, SimpleNamespace(SourceTimestamp=source, ServerTimestamp=server), (node, value))
    assert scheduled == [order.hand_over] and delivered == []  # handed over once, after the publish's last
    scheduled[0]()
    assert [(node, value) for node, value in delivered] == [
        ("A", 1), ("B", "x"), ("B", "y"), ("A", 2), ("A", 3), ("B", "z")]
    assert [v for n, v in delivered if n == "A"] == [1, 2, 3] and [v for n, v in delivered if n == "B"] == ["x", "y", "z"]


def _unit_link(tmp_path, published: list | None = None):
    """A PlcLink on the test's configuration with no PLC behind it; what it publishes, (key, message) in
    ``published``."""
    from cellsim.bridges.plc import PlcLink

    loaded = load_bridge(plc_config(tmp_path, 4840, "none", "  insecure_because: a unit test\n"))
    published = [] if published is None else published

    class Session:
        def declare_publisher(self, key):
            return type("P", (), {"put": lambda self, payload: published.append((key, json.loads(payload)))})()

    return loaded, PlcLink("welding_cell", loaded.config.plc, Session(), loaded.samples, loaded.commands, loaded.safe,
                           queue.Queue())


def test_the_daemons_heartbeat_goes_to_the_plc_only_once_it_took_every_command_node(tmp_path):
    """OPC UA applies each node of a write on its own: a command node the PLC refuses (its type, range or access) would
    leave the old command standing under a heartbeat that still counts. The heartbeat is written after the command
    nodes, and not at all while any entity's last command was refused: the PLC's own watchdog then acts."""
    import asyncio

    from asyncua import ua

    loaded, link = _unit_link(tmp_path)
    heartbeat = loaded.config.plc.command_heartbeat
    welder = list(loaded.config.plc.entities["welder"].commands.values())
    writes, refusing = [], {"on": True}

    class Client:
        def get_node(self, node):
            return node

        async def write_values(self, nodes, values):
            writes.append(list(nodes))
            if refusing["on"] and welder[0] in nodes:
                raise RuntimeError("BadTypeMismatch")

    link._client = Client()
    command = [(node, 1, ua.VariantType.Int32) for node in welder]

    async def run():
        await link._write("welder", command, 7)
        assert link.refused == {"welder"} and all(heartbeat not in w for w in writes)
        refusing["on"] = False
        await link._write("welder", command, 8)
        assert link.refused == set() and writes[-1] == [heartbeat] and writes[-2] == welder

    asyncio.run(run())


def test_a_plc_slower_than_the_command_cycle_gets_the_newest_command_next_never_a_backlog(tmp_path):
    """The audit's case: each write took 30 ms against a 40 ms cycle of two writes, so the commands piled up and the
    twin's safe command reached the PLC 2 s after the twin was lost, under a heartbeat that kept moving. While a write
    is under way, each entity's newest command replaces the one waiting: the next write is the safe command."""
    import asyncio
    import threading

    loaded, link = _unit_link(tmp_path)
    heartbeat = loaded.config.plc.command_heartbeat
    mode_node = loaded.config.plc.entities["welder"].commands["safety_mode_request"]
    writes, started = [], threading.Event()
    loop = asyncio.new_event_loop()
    release = asyncio.Event()

    class Client:
        def get_node(self, node):
            return node

        async def write_values(self, nodes, values):
            started.set()
            await release.wait()  # the PLC is slow: held until the test lets it take the writes
            writes.append({n: v.Value.Value for n, v in zip(nodes, values)})

    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        link._loop, link._client, link.connected = loop, Client(), True
        working = {"safety_mode_request": "normal", "activity_request": "welding", "command": 1.0}
        link.send("welder", working)
        assert started.wait(10.0)  # the first write is under way, held
        for _ in range(50):
            link.send("welder", working)  # 2 s of the twin's commands at 0.04 s, behind it
        link.send("welder", None)  # the twin is lost: the safe command
        loop.call_soon_threadsafe(release.set)
        done = asyncio.run_coroutine_threadsafe(_written(link), loop)
        done.result(10.0)
    finally:
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10.0)
    commands = [w for w in writes if heartbeat not in w]
    beats = [w[heartbeat] for w in writes if heartbeat in w]
    safe = link.commands["welder"].types[link.commands["welder"].names.index("safety_mode_request")]
    assert len(commands) == 2  # the one under way, then only the newest: the safe command
    assert commands[1][mode_node] == to_node_code(safe, loaded.safe["welder"]["safety_mode_request"])
    assert commands[0][mode_node] != commands[1][mode_node]
    assert beats == [1, 2]  # the heartbeat counts one per command written, none for those replaced


async def _written(link) -> None:
    """Until nothing waits to be written and no drain runs (polled on the loop, each step yielding to the writes)."""
    import asyncio

    while link._draining or link._pending:
        await asyncio.sleep(0)


def to_node_code(ctype, value):
    from cellsim.bridges.opcua import to_node

    return to_node(ctype, value)


def test_the_plcs_certificate_given_alone_is_trusted_as_it_is_and_never_replaced(tmp_path):
    """docs/security.md gives the daemon's machine the PLC's certificate, not its key: it is the one trusted, byte for
    byte (a pair was made over it before, so the daemon pinned a certificate nobody had); the daemon's own certificate
    without its key is an error naming the missing file, never a new pair over it."""
    import shutil

    from cellsim.live.pki import opcua_files, opcua_peer_certificate

    made = tmp_path / "plc_machine"
    plc_certificate, _ = opcua_files(made, "plc")
    daemon = tmp_path / "daemon_machine"
    daemon.mkdir()
    shutil.copy(plc_certificate, daemon / "opcua-plc.pem")
    given = (daemon / "opcua-plc.pem").read_bytes()
    assert opcua_peer_certificate(daemon, "plc") == daemon / "opcua-plc.pem"
    assert (daemon / "opcua-plc.pem").read_bytes() == given and not (daemon / "opcua-plc.key").exists()
    mine, key = opcua_files(daemon, "bridge")  # its own pair, made on first use
    key.unlink()
    before = mine.read_bytes()
    with pytest.raises(OSError, match="opcua-bridge.key"):
        opcua_files(daemon, "bridge")
    assert mine.read_bytes() == before
