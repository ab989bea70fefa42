"""Zenoh sessions stay on loopback, with multicast scouting off, unless the user configures otherwise."""

from __future__ import annotations

import json
import socket
import threading

import pytest

from cellsim.live.session import DEFAULT_ENDPOINT, SessionConfigError, session_config


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _get(config, key):
    return json.loads(config.get_json(key))


def test_defaults_turn_multicast_off_and_stay_on_loopback():
    twin = session_config(listen_by_default=True)
    other = session_config()
    for config in (twin, other):
        assert _get(config, "scouting/multicast/enabled") is False
        assert _get(config, "scouting/gossip/enabled") is False
    # the twin routes between everyone else, who are its clients
    assert (_get(twin, "mode"), _get(other, "mode")) == ("router", "client")
    assert _get(session_config(listen=["tcp/127.0.0.1:7600"]), "mode") == "peer"
    assert _get(twin, "listen/endpoints") == [DEFAULT_ENDPOINT]
    assert _get(other, "connect/endpoints") == [DEFAULT_ENDPOINT]
    assert _get(other, "listen/endpoints") == []  # not every interface


@pytest.mark.parametrize("endpoint", ["127.0.0.1:7447", "tcp/127.0.0.1", "tcp/127.0.0.1:99999", "tcp//:1", ""])
def test_a_bad_endpoint_is_one_line(endpoint):
    with pytest.raises(SessionConfigError, match="not a Zenoh endpoint"):
        session_config(connect=[endpoint])


def test_a_config_file_wins_over_the_defaults_it_sets(tmp_path):
    path = tmp_path / "zenoh.json5"
    path.write_text('{ scouting: { multicast: { enabled: true } }, connect: { endpoints: ["tcp/127.0.0.1:7500"] } }')
    config = session_config(config_file=path)
    assert _get(config, "scouting/multicast/enabled") is True  # the user asked for it
    assert _get(config, "connect/endpoints") == ["tcp/127.0.0.1:7500"]  # no default added
    assert _get(config, "scouting/gossip/enabled") is False


def test_a_bad_config_file_is_one_line(tmp_path):
    path = tmp_path / "zenoh.json5"
    path.write_text("{ mode: ")
    with pytest.raises(SessionConfigError) as e:
        session_config(config_file=path)
    assert "not a usable Zenoh configuration" in str(e.value) and "\n" not in str(e.value)


def test_two_sessions_talk_over_loopback():
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    twin = zenoh.open(session_config(listen=[endpoint]))
    try:
        peer = zenoh.open(session_config(connect=[endpoint]))
        try:
            got = threading.Event()
            received = []

            def on_sample(sample):
                received.append(sample.payload.to_string())
                got.set()

            subscriber = twin.declare_subscriber("cellsim/test/hello", on_sample)
            publisher = peer.declare_publisher("cellsim/test/hello")
            # the subscription reaches the peer asynchronously: repeat until heard, with a deadline
            for _ in range(200):
                publisher.put("hi")
                if got.wait(0.025):
                    break
            assert received and received[0] == "hi"
            subscriber.undeclare()
        finally:
            peer.close()
    finally:
        twin.close()
