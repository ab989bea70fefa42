"""Zenoh sessions that stay on this machine unless the user says otherwise.

Zenoh's own defaults scout by UDP multicast and listen on every interface.
Every session cellsim opens starts from :func:`session_config`, which

* turns multicast scouting and gossip off (a config file may turn them on again
  explicitly: its keys win over these defaults);
* listens on, or connects to, the endpoints given (``listen``, ``connect``: the
  networked commands' ``--listen`` and ``--connect``); when none are given, by
  argument or file, the twin listens on ``tls/127.0.0.1:7447``
  (``listen_by_default``) and every other process connects to it;
* makes the twin a Zenoh *router* and the others *clients* of it (peers when
  they listen themselves): every message between the emulator, the bridge
  daemon and the dashboard goes through the twin, and they reach each other
  with no scouting at all.

* is secure: TLS with mutual authentication by certificates of the cell's CA
  (:mod:`cellsim.live.pki`), one role per process, and, on a session that listens
  (the twin), access control by the certificates' common names
  (:mod:`cellsim.live.access`). Endpoints are ``tls/`` (or ``quic/``, also TLS).
  Only ``insecure=True`` (``--insecure``) gives plain TCP with no authentication,
  on loopback only.

The commands that open these sessions: ``cellsim live``, ``emulate``, ``bridge``,
``twin-mode``, ``dashboard``.

Endpoints are Zenoh locators such as ``tls/127.0.0.1:7447``; anything else is
refused with one line before a session is opened.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

DEFAULT_ENDPOINT = "tls/127.0.0.1:7447"
"""Where the twin listens and the other processes connect when nothing is configured."""
INSECURE_ENDPOINT = "tcp/127.0.0.1:7447"
"""The same, with ``--insecure``."""
SECURE_PROTOCOLS = ("tls", "quic")
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]")

_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|unixsock-stream|ws)/(\[[0-9a-fA-F:]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")


class SessionConfigError(ValueError):
    """A bad endpoint or Zenoh configuration file (the message is one line)."""


def check_endpoint(endpoint: str, flag: str) -> str:
    match = _ENDPOINT.match(endpoint)
    if not match or not 0 < int(match.group(3)) < 65536:
        raise SessionConfigError(
            f"{flag} {endpoint!r}: not a Zenoh endpoint (expected e.g. {DEFAULT_ENDPOINT})"
        )
    return endpoint


def session_config(
    *,
    role: str,
    keys: str | Path | None = None,
    insecure: bool = False,
    listen: list[str] = (),
    connect: list[str] = (),
    config_file: str | Path | None = None,
    listen_by_default: bool = False,
    wait: float = 30.0,
):
    """A ``zenoh.Config`` for a cellsim process running as ``role`` (see the module docstring).

    ``keys``: the folder of the cell's keys (default :func:`~cellsim.live.pki.default_keys_dir`);
    it must hold ``ca.pem`` and the role's certificate and key. ``insecure``: plain TCP on
    loopback, no authentication, no access control (``keys`` unused).
    ``listen_by_default``: with no endpoint configured at all, listen on
    :data:`DEFAULT_ENDPOINT` (the twin) instead of connecting to it (everyone else).
    ``wait``: how long (s) a client's session waits at opening for the twin to be reachable.

    Every endpoint, whether from ``listen``, ``connect`` or the file, passes one rule
    (:func:`check_endpoints`); a file may not touch what makes the session secure
    (:data:`RESERVED`). Raises :class:`SessionConfigError` (one line) before anything is opened.
    """
    import zenoh

    from cellsim.live import pki

    listen = check_endpoints(listen, "--listen", insecure=insecure, role=role, listens=True)
    connect = check_endpoints(connect, "--connect", insecure=insecure, role=role, listens=False)
    files = None
    if not insecure:
        try:
            folder = Path(keys) if keys is not None else pki.default_keys_dir()
            files = pki.role_files(folder, role)
            pki.check_pinned(folder)
        except pki.KeysError as e:
            raise SessionConfigError(str(e)) from None
    user: dict = {}
    if config_file is not None:
        path = Path(config_file)
        try:
            config = zenoh.Config.from_file(str(path))
        except Exception as e:  # noqa: BLE001 - zenoh raises its own ZError with a multi-line text
            raise SessionConfigError(f"{path}: not a usable Zenoh configuration ({_one_line(e)})") from None
        user = _set_by_file(config)
        _check_file(path, user, config, insecure=insecure, role=role)
    else:
        config = zenoh.Config()
    if "mode" not in user:
        mode = "router" if listen_by_default else ("peer" if listen else "client")
        config.insert_json5("mode", json.dumps(mode))
        if mode == "client":  # the twin may start after it: wait for it, then reconnect if it goes
            config.insert_json5("connect/timeout_ms", json.dumps({"client": max(0, int(wait * 1000))}))
    if "scouting/multicast/enabled" not in user:
        config.insert_json5("scouting/multicast/enabled", "false")
    if "scouting/gossip/enabled" not in user:
        config.insert_json5("scouting/gossip/enabled", "false")
    if not listen and not connect and not _has_endpoints(user):
        (listen if listen_by_default else connect).append(INSECURE_ENDPOINT if insecure else DEFAULT_ENDPOINT)
    if listen or not _under(user, "listen/endpoints"):
        config.insert_json5("listen/endpoints", json.dumps(listen))
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    # the only links this session may make or take, whatever a scout or a peer's gossip advertises
    config.insert_json5("transport/link/protocols", json.dumps(["tcp"] if insecure else list(SECURE_PROTOCOLS)))
    if files is not None:
        for key, value in {
            "root_ca_certificate": str(files.ca),
            "enable_mtls": True,
            "listen_certificate": str(files.certificate),
            "listen_private_key": str(files.key),
            "connect_certificate": str(files.certificate),
            "connect_private_key": str(files.key),
            "verify_name_on_connect": True,  # the server must be the twin: only its certificate names a host
            "close_link_on_expiration": True,
        }.items():
            config.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
    listens = bool(listen or (_listed(config, "listen/endpoints") if _under(user, "listen/endpoints") else []))
    if files is not None and listens:  # whoever listens enforces the rules
        from cellsim.live.access import access_control

        config.insert_json5("access_control", json.dumps(access_control()))
    return config


RESERVED = ("transport/link/tls", "transport/link/protocols", "transport/auth", "access_control",
            "adminspace/permissions/write", "plugins", "plugins_loading")
"""What a configuration file may not set: the session's TLS and certificates, the protocols it may use,
other authentication, the access control, remote writes to its configuration, plugins (which open
listeners of their own). cellsim sets these; ``--keys`` and ``--insecure`` choose among them."""
_TUNABLE = ("transport/link/tls/so_sndbuf", "transport/link/tls/so_rcvbuf")
"""Socket buffer sizes: under ``transport/link/tls`` but no part of its security."""


def check_endpoints(endpoints, where: str, *, insecure: bool, role: str, listens: bool) -> list[str]:
    """The one rule every endpoint passes, whatever its source (``where``: ``--listen``, ``--connect``, or
    a file's key): a Zenoh locator; ``tls/`` or ``quic/``, or plain ``tcp/`` on loopback only with
    ``--insecure``; and, on a secure session, only the twin listens (only its certificate may serve TLS,
    :data:`cellsim.live.pki.SERVER_ROLE`)."""
    from cellsim.live.pki import SERVER_ROLE

    checked = [_check_security(check_endpoint(e, where), where, insecure) for e in endpoints]
    if checked and listens and not insecure and role != SERVER_ROLE:
        raise SessionConfigError(f"{where} {checked[0]!r}: only the {SERVER_ROLE} listens; the {role} connects to it "
                                 f"(no other role's certificate may serve TLS: docs/security.md, \"Roles\")")
    return checked


def _set_by_file(config) -> dict:
    """What a configuration sets: every leaf (``a/b/c``) whose value differs from Zenoh's default."""
    import zenoh

    return dict(_leaves(json.loads(str(config)), json.loads(str(zenoh.Config())), ""))


def _leaves(value, default, prefix: str):
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _leaves(item, default.get(key) if isinstance(default, dict) else None, f"{prefix}{key}/")
    elif value != default:
        yield prefix.rstrip("/"), value


def _check_file(path: Path, user: dict, config, *, insecure: bool, role: str) -> None:
    for key in user:
        if key not in _TUNABLE and any(_within(key, reserved) for reserved in RESERVED):
            raise SessionConfigError(f"{path}: {key}: set by cellsim, not by a configuration file (TLS, keys and "
                                     "access control follow --keys and --insecure)")
    for name, listens in (("listen/endpoints", True), ("connect/endpoints", False)):
        # every endpoint the file leaves in force, those equal to Zenoh's defaults included (a per-mode list of its
        # own replaces cellsim's, so 'peer: [tcp/[::]:0]' would listen on every interface unchecked)
        listed = _listed(config, name) if _under(user, name) else []
        check_endpoints(listed, f"{path}: {name}", insecure=insecure, role=role, listens=listens)
    if insecure:
        for key in ("scouting/multicast/enabled", "scouting/gossip/enabled"):
            if user.get(key):
                raise SessionConfigError(f"{path}: {key}: --insecure stays on loopback, with no scouting")


def _within(key: str, prefix: str) -> bool:
    return key == prefix or key.startswith(prefix + "/")


def _under(user: dict, prefix: str) -> bool:
    return any(_within(key, prefix) for key in user)


def _listed(config, prefix: str) -> list[str]:
    """Every endpoint ``config`` lists under ``prefix`` (``listen/endpoints``), as a list or per mode, whether a file
    set it or it is Zenoh's default."""
    value = json.loads(str(config))
    for part in prefix.split("/"):
        value = value.get(part) if isinstance(value, dict) else None
    values = list(value.values()) if isinstance(value, dict) else [value]
    return [e for v in values for e in (v if isinstance(v, list) else [v] if isinstance(v, str) else [])]


def _endpoints(user: dict, prefix: str) -> list[str]:
    """Every endpoint a file lists under ``prefix``, as a list or per mode (``{router: [...], peer: [...]}``)."""
    found = []
    for key, value in user.items():
        if _within(key, prefix):
            found += value if isinstance(value, list) else [value] if isinstance(value, str) else []
    return found


def _check_security(endpoint: str, flag: str, insecure: bool) -> str:
    protocol, _, rest = endpoint.partition("/")
    host = rest.rsplit(":", 1)[0]
    if insecure:
        if protocol != "tcp" or host not in LOOPBACK_HOSTS:
            raise SessionConfigError(f"{flag} {endpoint!r}: --insecure allows plain tcp/ on loopback only "
                                     f"(e.g. {INSECURE_ENDPOINT})")
    elif protocol not in SECURE_PROTOCOLS:
        raise SessionConfigError(f"{flag} {endpoint!r}: {protocol}/ has no encryption or authentication; "
                                 f"use tls/ (e.g. {DEFAULT_ENDPOINT}), or --insecure on loopback")
    return endpoint


def _has_endpoints(user: dict) -> bool:
    return bool(_endpoints(user, "listen/endpoints") or _endpoints(user, "connect/endpoints"))


def _one_line(error: Exception) -> str:
    return " ".join(str(error).split())[:300]
