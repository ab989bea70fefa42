"""Zenoh sessions that stay on this machine unless the user says otherwise.

Zenoh's own defaults scout by UDP multicast and listen on every interface.
Every session cellsim opens starts from :func:`session_config`, which

* turns multicast scouting and gossip off (a config file may turn them on again
  explicitly: its keys win over these defaults);
* listens on, or connects to, the endpoints given (``listen``, ``connect``: the
  networked commands' ``--listen`` and ``--connect``); when none are given, by
  argument or file, the twin listens on ``tcp/127.0.0.1:7447``
  (``listen_by_default``) and every other process connects to it;
* makes the twin a Zenoh *router* and the others *clients* of it (peers when
  they listen themselves): every message between the emulator, the bridge
  daemon and the dashboard goes through the twin, and they reach each other
  with no scouting at all.

The commands that open these sessions: ``cellsim live``, ``emulate``, ``twin-mode``.

Endpoints are Zenoh locators such as ``tcp/127.0.0.1:7447``; anything else is
refused with one line before a session is opened.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where the twin listens and the other processes connect when nothing is configured."""

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
    listen: list[str] = (),
    connect: list[str] = (),
    config_file: str | Path | None = None,
    listen_by_default: bool = False,
    wait: float = 30.0,
):
    """A ``zenoh.Config`` for a cellsim process (see the module docstring).

    ``listen_by_default``: with no endpoint configured at all, listen on
    :data:`DEFAULT_ENDPOINT` (the twin) instead of connecting to it (everyone else).
    ``wait``: how long (s) a client's session waits at opening for the twin to be reachable.
    """
    import zenoh

    listen = [check_endpoint(e, "--listen") for e in listen]
    connect = [check_endpoint(e, "--connect") for e in connect]
    user: dict = {}
    if config_file is not None:
        path = Path(config_file)
        try:
            config = zenoh.Config.from_file(str(path))
        except Exception as e:  # noqa: BLE001 - zenoh raises its own ZError with a multi-line text
            raise SessionConfigError(f"{path}: not a usable Zenoh configuration ({_one_line(e)})") from None
        # what the file sets: the keys whose value differs from Zenoh's default
        default = zenoh.Config()
        user = {key: json.loads(config.get_json(key)) for key in _KEYS if config.get_json(key) != default.get_json(key)}
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
        (listen if listen_by_default else connect).append(DEFAULT_ENDPOINT)
    if listen or "listen/endpoints" not in user:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    return config


_KEYS = ("mode", "scouting/multicast/enabled", "scouting/gossip/enabled", "listen/endpoints", "connect/endpoints")


def _has_endpoints(user: dict) -> bool:
    def given(value) -> bool:
        if isinstance(value, dict):  # per-mode endpoints: {"peer": [...], "router": [...]}
            return any(given(v) for v in value.values())
        return bool(value)

    return given(user.get("listen/endpoints")) or given(user.get("connect/endpoints"))


def _one_line(error: Exception) -> str:
    return " ".join(str(error).split())[:300]
