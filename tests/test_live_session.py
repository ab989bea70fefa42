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
    twin = session_config(role="twin", listen_by_default=True)
    other = session_config(role="observer")
    for config in (twin, other):
        assert _get(config, "scouting/multicast/enabled") is False
        assert _get(config, "scouting/gossip/enabled") is False
    # the twin routes between everyone else, who are its clients
    assert (_get(twin, "mode"), _get(other, "mode")) == ("router", "client")
    assert _get(session_config(role="emulator", listen=["tls/127.0.0.1:7600"]), "mode") == "peer"
    assert _get(twin, "listen/endpoints") == [DEFAULT_ENDPOINT]
    assert _get(other, "connect/endpoints") == [DEFAULT_ENDPOINT]
    assert _get(other, "listen/endpoints") == []  # not every interface


@pytest.mark.parametrize("endpoint", ["127.0.0.1:7447", "tls/127.0.0.1", "tls/127.0.0.1:99999", "tcp//:1", ""])
def test_a_bad_endpoint_is_one_line(endpoint):
    with pytest.raises(SessionConfigError, match="not a Zenoh endpoint"):
        session_config(role="observer", connect=[endpoint])


def test_a_config_file_wins_over_the_defaults_it_sets(tmp_path):
    path = tmp_path / "zenoh.json5"
    path.write_text('{ scouting: { multicast: { enabled: true } }, connect: { endpoints: ["tls/127.0.0.1:7500"] } }')
    config = session_config(role="observer", config_file=path)
    assert _get(config, "scouting/multicast/enabled") is True  # the user asked for it
    assert _get(config, "connect/endpoints") == ["tls/127.0.0.1:7500"]  # no default added
    assert _get(config, "scouting/gossip/enabled") is False


def test_a_bad_config_file_is_one_line(tmp_path):
    path = tmp_path / "zenoh.json5"
    path.write_text("{ mode: ")
    with pytest.raises(SessionConfigError) as e:
        session_config(role="observer", config_file=path)
    assert "not a usable Zenoh configuration" in str(e.value) and "\n" not in str(e.value)


def test_two_sessions_talk_over_loopback():
    import zenoh

    endpoint = f"tls/127.0.0.1:{free_port()}"
    twin = zenoh.open(session_config(role="twin", listen=[endpoint]))
    try:
        peer = zenoh.open(session_config(role="emulator", connect=[endpoint]))
        try:
            got = threading.Event()
            received = []

            def on_sample(sample):
                received.append(sample.payload.to_string())
                got.set()

            subscriber = twin.declare_subscriber("cellsim/test/physical/hello", on_sample)
            publisher = peer.declare_publisher("cellsim/test/physical/hello")
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


def test_sessions_are_mutual_tls_with_the_roles_certificate_and_whoever_listens_enforces_the_roles(cell_keys):
    twin = session_config(role="twin", listen_by_default=True)
    tls = _get(twin, "transport/link/tls")
    assert tls["enable_mtls"] is True and tls["verify_name_on_connect"] is True
    assert tls["root_ca_certificate"] == str(cell_keys / "ca.pem")
    assert tls["listen_certificate"] == str(cell_keys / "twin.pem")
    acl = _get(twin, "access_control")
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert {s["id"]: s["cert_common_names"] for s in acl["subjects"]}["observer"] == ["observer"]
    client = session_config(role="observer")
    assert _get(client, "transport/link/tls")["connect_certificate"] == str(cell_keys / "observer.pem")
    assert _get(client, "access_control")["enabled"] is False  # a client does not route: the twin enforces


@pytest.mark.parametrize("args, expected", [
    ({"connect": ["tcp/127.0.0.1:7447"]}, "tcp/ has no encryption or authentication"),
    ({"connect": ["tcp/10.0.0.5:7447"], "insecure": True}, "--insecure allows plain tcp/ on loopback only"),
    ({"connect": ["tls/127.0.0.1:7447"], "insecure": True}, "--insecure allows plain tcp/ on loopback only"),
    ({"role": "intruder"}, "'intruder' is no role"),
])
def test_plain_tcp_needs_insecure_and_loopback_and_a_role_must_be_one(args, expected):
    with pytest.raises(SessionConfigError, match=expected):
        session_config(**{"role": "observer", **args})


def test_insecure_is_plain_tcp_on_loopback_with_no_access_control():
    config = session_config(role="twin", insecure=True, listen_by_default=True)
    assert _get(config, "listen/endpoints") == ["tcp/127.0.0.1:7447"]
    assert _get(config, "access_control")["enabled"] is False
    assert _get(config, "transport/link/tls")["root_ca_certificate"] is None


def test_missing_keys_say_how_to_make_them(tmp_path):
    with pytest.raises(SessionConfigError, match=r"no ca.pem, observer.pem, observer.key .*cellsim keys init"):
        session_config(role="observer", keys=tmp_path)
