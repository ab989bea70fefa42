"""``cellsim export RUN --mcap FILE``: the black box as MCAP, read back with the mcap reader (not
the writer that made it), every message per channel, the arms' frames and the cell in 3D. The frames
and the scene are Foxglove's official messages: every one decodes with the official schema, by a
decoder nobody here wrote (mcap-protobuf-support, Google's protobuf)."""

from __future__ import annotations

import json
import time
import sqlite3
import subprocess
import sys
from collections import Counter

import pytest
from mcap.reader import make_reader

from cellsim.scenario import load_scenario
from cellsim.simulation import simulate

from conftest import ROOT

ASSEMBLY_BENCH = ROOT / "scenarios" / "assembly_bench.yaml"
OFFICIAL = ("foxglove.FrameTransforms", "foxglove.SceneUpdate")


def _official_schema(name: str) -> bytes:
    """Foxglove's own schema of ``name`` as foxglove-sdk ships it (a protobuf FileDescriptorSet)."""
    import foxglove.messages

    return bytes(getattr(foxglove.messages, name.removeprefix("foxglove.")).get_schema().data)


def _decode(schema_name: str, encoding: str, schema_data: bytes, data: bytes):
    """A message as plain data: JSON as JSON; protobuf decoded with the schema it was declared with, by
    mcap-protobuf-support and Google's protobuf (zero values written out, as Foxglove shows them)."""
    from types import SimpleNamespace

    from google.protobuf.json_format import MessageToDict
    from mcap_protobuf.decoder import DecoderFactory

    if encoding in ("json", "jsonschema"):
        return json.loads(data)
    assert encoding == "protobuf", encoding
    decoder = DecoderFactory().decoder_for("protobuf", SimpleNamespace(id=hash(schema_name) & 0xFFFF, name=schema_name,
                                                                       encoding="protobuf", data=schema_data))
    return MessageToDict(decoder(data), preserving_proto_field_name=True, always_print_fields_with_no_presence=True)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    base = tmp_path_factory.mktemp("export")
    simulate(load_scenario(ASSEMBLY_BENCH), base / "run", duration=8.0)
    done = subprocess.run([sys.executable, "-m", "cellsim", "export", str(base / "run"), "--mcap", str(base / "run.mcap")],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    with open(base / "run.mcap", "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        messages = [(channel.topic, schema.name, schema.encoding, message.log_time,
                     _decode(schema.name, schema.encoding, schema.data, message.data))
                    for schema, channel, message in reader.iter_messages(log_time_order=True)]
        declared = {channel.topic: (schema.name, schema.encoding, schema.data, channel.message_encoding)
                    for schema, channel, _ in reader.iter_messages(topics=["/tf", "/scene"])}
    # the frames and the scene are declared with Foxglove's official schemas, exactly as foxglove-sdk has them
    for topic, name in (("/tf", OFFICIAL[0]), ("/scene", OFFICIAL[1])):
        assert declared[topic] == (name, "protobuf", _official_schema(name), "protobuf")
    return base, done.stdout, summary, messages


def test_every_black_box_message_is_in_the_mcap_per_channel_with_the_same_count(exported):
    base, stdout, summary, messages = exported
    db = sqlite3.connect(base / "run" / "blackbox.sqlite")
    recorded = dict(db.execute("SELECT channel, count(*) FROM messages GROUP BY channel").fetchall())
    channels = [r[0] for r in db.execute("SELECT name FROM channels")]
    counts = Counter(topic for topic, *_ in messages)
    assert {"/" + c.replace(".", "/"): recorded.get(c, 0) for c in channels} == {
        "/" + c.replace(".", "/"): counts["/" + c.replace(".", "/")] for c in channels}
    assert sum(recorded.values()) > 1000 and f"{sum(recorded.values()):,} messages of {len(channels)} channels" in stdout
    # the values and times are the black box's, with a JSON schema per channel
    first = db.execute("SELECT t, payload FROM messages WHERE channel = 'loader.safety_mode' ORDER BY rowid").fetchall()
    shown = [(log, data) for topic, _, _, log, data in messages if topic == "/loader/safety_mode"]
    assert [(round(t * 1e9), json.loads(p)["value"]) for t, p in first] == [(log, d["value"]) for log, d in shown]
    schemas = {topic: (name, encoding) for topic, name, encoding, *_ in messages}
    assert schemas["/loader/safety_mode"] == ("cellsim.loader.safety_mode", "jsonschema")


def test_the_arms_links_are_frame_transforms_and_the_cell_a_scene_update(exported):
    base, _, summary, messages = exported
    sc = load_scenario(ASSEMBLY_BENCH).scenario
    tf = [d for topic, name, _, _, d in messages if topic == "/tf" and name == "foxglove.FrameTransforms"]
    scene = [d for topic, name, _, _, d in messages if topic == "/scene" and name == "foxglove.SceneUpdate"]
    # one /tf per recorded joint state (the arms' times, not the people's too), strictly in time order
    db = sqlite3.connect(base / "run" / "blackbox.sqlite")
    joint_times = sorted({t for (t,) in db.execute(
        "SELECT t FROM messages WHERE channel IN ('loader.joint_positions', 'assembler.joint_positions')")})
    tf_times = [log for topic, _, _, log, _ in messages if topic == "/tf"]
    assert tf_times == [round(t * 1e9) for t in joint_times] and len(tf) > 50
    assert len(scene) >= len(tf)
    frames = {t["child_frame_id"]: t for t in tf[0]["transforms"]}
    for robot in ("loader", "assembler"):
        base_link = frames[f"{robot}/base_link"]["translation"]
        assert [base_link[k] for k in "xyz"] == pytest.approx(list(sc.entities[robot].base_position), abs=1e-9)
    # the arms move: a wrist frame is somewhere else later
    wrist = [[t["translation"][k] for k in "xyz"] for m in tf for t in m["transforms"] if t["child_frame_id"] == "loader/wrist_3_link"]
    assert max(abs(a - b) for a, b in zip(wrist[0], max(wrist, key=lambda w: abs(w[0] - wrist[0][0])))) > 0.3
    # the first scene holds every fixture as a cube of its size, where the layout puts it
    cubes = [c for e in scene[0]["entities"] for c in e.get("cubes", [])]
    for fixture in sc.layout.fixtures.values():
        assert any([c["size"][k] for k in "xyz"] == pytest.approx(list(fixture.size))
                   and [c["pose"]["position"][k] for k in "xyz"] == pytest.approx(list(fixture.center)) for c in cubes)
    # every scene is whole (after a seek Foxglove draws a topic's latest message alone: the audit found fixtures and
    # sensor volumes sent only in the first), and the operator's body follows the recorded positions
    db = sqlite3.connect(base / "run" / "blackbox.sqlite")
    xy = [json.loads(p)["value"] for (p,) in db.execute("SELECT payload FROM messages WHERE channel = 'operator.position'")]
    ids = {e["id"] for e in scene[0]["entities"]}
    assert all({e["id"] for e in later["entities"]} == ids for later in scene)
    # each entity says which geometry it is (an audit found Foxglove's entity list naming none of the body regions)
    names = {m["value"] for e in scene[0]["entities"] for m in e.get("metadata", []) if m["key"] == "name"}
    assert {"operator/hand_right", "operator/forearm_left", "fixture/bench"} <= {n.rsplit("/", 1)[0] for n in names} | names
    positions = [[c["pose"]["position"][k] for k in "xy"] for e in scene[-1]["entities"]
                 for c in e.get("cylinders", []) + e.get("spheres", [])]
    assert any(p == pytest.approx(xy[-1], abs=0.35) for p in positions)


def test_a_missing_run_is_one_line_and_writes_nothing(tmp_path):
    done = subprocess.run([sys.executable, "-m", "cellsim", "export", str(tmp_path / "nothing"), "--mcap",
                           str(tmp_path / "x.mcap")], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1 and "no such run folder" in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_the_live_twin_is_served_on_foxglove_websocket(tmp_path):
    """``cellsim live --foxglove PORT``: a Foxglove client (its WebSocket protocol, spoken here with the
    websockets package) sees every channel advertised with its schema, and gets the twin's channels,
    the arms' frames and the cell as it runs; the server listens on loopback."""
    import struct

    from websockets.sync.client import connect

    from conftest import WELDING_CELL
    from live_processes import free_port, processes, wait_listening

    port, fox = free_port(), free_port()
    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", f"tls/127.0.0.1:{port}",
                      "--quiet", "--wait-physical", "0", "--foxglove", str(fox)], tmp_path / "twin.log")
        wait_listening(twin, fox, 120, "the Foxglove server", ready="Foxglove on ws://127.0.0.1:")
        with connect(f"ws://127.0.0.1:{fox}", subprotocols=["foxglove.sdk.v1"], open_timeout=30) as ws:
            channels = {}
            while not {"/robot/safety_mode", "/tf", "/scene", "/light_barrier/broken"} <= set(channels):
                message = json.loads(ws.recv(timeout=30))
                if message["op"] == "serverInfo":  # read-only: no client publishing, services or parameters
                    assert message["capabilities"] == []
                if message["op"] == "advertise":
                    channels.update({c["topic"]: c for c in message["channels"]})
            import base64

            for topic, name in (("/tf", OFFICIAL[0]), ("/scene", OFFICIAL[1])):  # the official schemas, no other
                assert channels[topic]["schemaName"] == name and channels[topic]["encoding"] == "protobuf"
                assert base64.b64decode(channels[topic]["schema"]) == _official_schema(name)
            schema = json.loads(channels["/robot/safety_mode"]["schema"])
            assert "normal" in schema["properties"]["value"]["enum"]
            wanted = {i: topic for i, topic in enumerate(("/robot/safety_mode", "/tf", "/scene"), 1)}

            def subscribe(ids) -> None:
                ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": i, "channelId": channels[wanted[i]]["id"]} for i in ids]}))

            subscribe(list(wanted))
            got: dict = {}
            late = 0
            deadline = time.monotonic() + 60  # frames keep coming: a subscription never answered must still end
            while len(got) < len(wanted) or late < 2_000_000_000:
                assert time.monotonic() < deadline, (sorted(got), late, twin.output())
                frame = ws.recv(timeout=30)
                if isinstance(frame, bytes) and frame[0] == 1:  # messageData: op, subscription, log time, payload
                    subscription, log_time = struct.unpack_from("<IQ", frame, 1)
                    c = channels[wanted[subscription]]
                    schema_data = (base64.b64decode(c["schema"]) if c["encoding"] == "protobuf"
                                   else c["schema"].encode())
                    got.setdefault(wanted[subscription], _decode(c["schemaName"], c["encoding"], schema_data,
                                                                 frame[13:]))
                    late = max(late, log_time)
            # a client that subscribes 2 s into the run to a channel that has not changed since t = 0
            # (the curtain: nobody at the table) still gets its value, from the heartbeat
            wanted[4] = "/light_barrier/broken"
            subscribe([4])
            deadline = time.monotonic() + 30
            while "/light_barrier/broken" not in got:
                assert time.monotonic() < deadline, ("no /light_barrier/broken", channels["/light_barrier/broken"],
                                                     twin.output())
                frame = ws.recv(timeout=30)
                if isinstance(frame, bytes) and frame[0] == 1 and struct.unpack_from("<I", frame, 1)[0] == 4:
                    got["/light_barrier/broken"] = json.loads(frame[13:])
            assert got["/light_barrier/broken"]["t"] <= late / 1e9 + 1.2  # within a heartbeat, not at its next change
        assert twin.popen.poll() is None, twin.output()
        assert got["/robot/safety_mode"]["value"] in schema["properties"]["value"]["enum"]
        assert any(t["child_frame_id"] == "robot/base_link" for t in got["/tf"]["transforms"])
        assert any(e.get("cubes") for e in got["/scene"]["entities"])  # the fixtures
        assert got["/light_barrier/broken"]["value"] in (True, False)
        assert twin.stop() in (0, 1, 130)


@pytest.mark.parametrize("quiet", [["--quiet"], []])
def test_a_foxglove_port_in_use_is_one_line_and_exit_2_with_nothing_written(tmp_path, quiet):
    """Refused before the session opens, so nothing else is said first ("recording to ..." was)."""
    import socket

    from conftest import WELDING_CELL
    from live_processes import free_port

    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    try:
        done = subprocess.run([sys.executable, "-m", "cellsim", "live", str(WELDING_CELL), "--out", str(tmp_path / "twin"),
                               "--listen", f"tls/127.0.0.1:{free_port()}", *quiet, "--wait-physical", "0",
                               "--foxglove", str(taken.getsockname()[1])], capture_output=True, text=True, timeout=120, cwd=ROOT)
    finally:
        taken.close()
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "--foxglove" in done.stderr and "cannot serve" in done.stderr
    assert not (tmp_path / "twin").exists()
