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
    assert _get(session_config(role="emulator", insecure=True, listen=["tcp/127.0.0.1:7600"]), "mode") == "peer"
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


def test_only_the_twin_listens_on_a_secure_session():
    """Only the twin's certificate may serve TLS (``cellsim.live.pki``): any other role asked to listen is
    refused in one line, from the command line or a file."""
    assert _get(session_config(role="twin", listen=["tls/127.0.0.1:7600"]), "listen/endpoints") == ["tls/127.0.0.1:7600"]
    for role in ("bridge", "emulator", "robot", "engineer", "observer"):
        with pytest.raises(SessionConfigError, match=f"only the twin listens; the {role} connects to it"):
            session_config(role=role, listen=["tls/127.0.0.1:7600"])


def _file(tmp_path, text: str):
    path = tmp_path / "zenoh.json5"
    path.write_text(text)
    return path


@pytest.mark.parametrize("insecure, text, expected", [
    # issue 32's attack: the --insecure listener on every interface, given in a file instead of --listen
    (True, '{ listen: { endpoints: ["tcp/0.0.0.0:7447"] } }', "listen/endpoints 'tcp/0.0.0.0:7447': --insecure allows plain tcp/ on loopback only"),
    (True, '{ listen: { endpoints: { router: ["tcp/0.0.0.0:7447"] } } }', "--insecure allows plain tcp/ on loopback only"),
    # the audit's: an endpoint equal to Zenoh's default for its mode was no change the check saw, and one other entry
    # kept cellsim from replacing the list (a plain listener on every interface)
    (True, '{ listen: { endpoints: { router: ["tcp/[::]:7447"], client: ["tcp/127.0.0.1:7448"] } } }',
     "listen/endpoints 'tcp/[::]:7447'"),
    (True, '{ mode: "peer", listen: { endpoints: { peer: ["tcp/[::]:0"], client: [] } } }', "listen/endpoints 'tcp/[::]:0'"),
    (False, '{ listen: { endpoints: ["tcp/127.0.0.1:7447"] } }', "tcp/ has no encryption or authentication"),
    (False, '{ connect: { endpoints: ["udp/127.0.0.1:7447"] } }', "udp/ has no encryption or authentication"),
    (False, '{ connect: { endpoints: ["tls/127.0.0.1:7447#root_ca_certificate=/tmp/x"] } }', "not a Zenoh endpoint"),
    (True, '{ scouting: { multicast: { enabled: true } } }', "scouting/multicast/enabled: --insecure stays on loopback"),
    (False, '{ transport: { link: { tls: { verify_name_on_connect: false } } } }', "transport/link/tls/verify_name_on_connect: set by cellsim"),
    (False, '{ transport: { link: { tls: { root_ca_certificate: "/tmp/other.pem" } } } }', "transport/link/tls/root_ca_certificate: set by cellsim"),
    (False, '{ transport: { link: { protocols: ["tcp", "tls"] } } }', "transport/link/protocols: set by cellsim"),
    (False, '{ access_control: { enabled: false, default_permission: "allow" } }', "access_control/default_permission: set by cellsim"),
    (False, '{ adminspace: { enabled: true, permissions: { write: true } } }', "adminspace/permissions/write: set by cellsim"),
])
def test_a_config_file_passes_the_same_rule_as_the_command_line(tmp_path, insecure, text, expected):
    with pytest.raises(SessionConfigError) as e:
        session_config(role="twin", insecure=insecure, listen_by_default=True, config_file=_file(tmp_path, text))
    assert expected in str(e.value) and str(e.value).startswith(str(tmp_path / "zenoh.json5")) and "\n" not in str(e.value)


def test_a_session_takes_only_the_protocols_its_security_allows(tmp_path):
    """Whatever a scout or a peer advertises, a secure session makes and takes TLS links only, an insecure one
    plain TCP only; a file may tune what is no part of security (socket buffers, timeouts)."""
    tuned = _file(tmp_path, '{ transport: { link: { tls: { so_sndbuf: 65536 } } }, queries_default_timeout: 5000 }')
    secure = session_config(role="twin", listen_by_default=True, config_file=tuned)
    assert _get(secure, "transport/link/protocols") == ["tls", "quic"]
    assert _get(secure, "transport/link/tls")["so_sndbuf"] == 65536 and _get(secure, "queries_default_timeout") == 5000
    assert _get(secure, "transport/link/tls")["verify_name_on_connect"] is True
    assert _get(session_config(role="observer", insecure=True), "transport/link/protocols") == ["tcp"]


def test_keys_made_before_roles_were_pinned_are_refused(tmp_path, cell_keys):
    """A folder whose observer certificate names hosts and may serve TLS (as every role's did before): its
    holder could pose as the twin, so no session is opened with those keys."""
    import datetime
    import shutil

    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    from cellsim.live import pki

    old = tmp_path / "old"
    shutil.copytree(cell_keys, old)
    ca_key = serialization.load_pem_private_key((old / "ca.key").read_bytes(), None)
    ca_cert = x509.load_pem_x509_certificate((old / "ca.pem").read_bytes())
    now = datetime.datetime.now(datetime.timezone.utc)
    key, cert = pki._role_certificate("observer", ca_key, ca_cert, pki._subject_names(pki.DEFAULT_HOSTS), now, 30)
    (old / "observer.pem").write_bytes(pki._pem_certificate(cert))
    (old / "observer.key").write_bytes(pki._pem_key(key))
    for role in ("twin", "bridge"):
        with pytest.raises(SessionConfigError, match=r"observer.pem: the observer's certificate may serve TLS .*cellsim keys init"):
            session_config(role=role, keys=old)


def test_a_server_holding_any_other_roles_certificate_gets_no_session_from_anyone(cell_keys):
    """Issue 32: with the twin gone, a process holding another role's certificate (the observer's, meant for
    shop-floor dashboards, or any other) serves TLS on the twin's port. Every client role (the bridge daemon,
    the emulator, the robot adapter, twin-mode's engineer, the dashboard's observer) refuses it; the same
    clients take the real twin's."""
    import zenoh
    from concurrent.futures import ThreadPoolExecutor

    from cellsim.live.pki import ROLES

    from live_processes import rogue_router

    clients = [r for r in ROLES if r != "twin"]

    def connects(role: str, port: int) -> bool:
        try:
            zenoh.open(session_config(role=role, connect=[f"tls/127.0.0.1:{port}"], wait=1.5)).close()
            return True
        except zenoh.ZError:
            return False

    # every server at once, each on its own port: the clients' refusals wait out their connect timeouts together
    ports: dict[str, int] = {}
    while len(ports) < len(ROLES):
        port = free_port()
        if port not in ports.values():
            ports[ROLES[len(ports)]] = port
    routers = []
    try:
        for server in ROLES:
            routers.append(rogue_router(cell_keys, server, ports[server]))
        pairs = [(server, client) for server in ROLES for client in clients]
        with ThreadPoolExecutor(len(pairs)) as pool:
            connected = dict(zip(pairs, pool.map(lambda pair: connects(pair[1], ports[pair[0]]), pairs)))
    finally:
        for router in routers:
            router.close()
    for server in ROLES:
        outcome = {client: connected[server, client] for client in clients}
        expected = server == "twin"
        assert outcome == {r: expected for r in clients}, (server, outcome)
