"""Who may do what on the twin's Zenoh network: the access control the twin enforces.

The twin is the Zenoh router every other process connects to (:mod:`cellsim.live.session`),
so it is where the rules are enforced. A process is known by its certificate's
common name, one role per process (:data:`cellsim.live.pki.ROLES`); anything a
role is not granted here is denied. The grants are least privilege for what each
process of cellsim does:

========  ==================================================================
twin      publishes its channels, status and commands; takes physical
          samples; answers twin-mode switches and "describe" (granted for a
          twin that connects to a separate router rather than being one)
bridge    publishes physical samples, diagnostics, robot requests and the ROS
          joint state; takes commands, twin modes and controller states;
          holds its liveliness token and watches the twin's
emulator  publishes physical samples, emulated controller states and its status;
          takes commands and controller requests; answers fault injections
robot     a robot controller's adapter: publishes its state, takes requests
engineer  watches everything; switches twin modes, injects faults, asks what
          the twin runs
observer  watches everything; asks what the twin runs; nothing else
========  ==================================================================

Flows are seen from the twin: *ingress* is what a process sends to it, *egress*
what it sends to the process.
"""

from __future__ import annotations

from dataclasses import dataclass

ANY_CELL = "cellsim/*"


@dataclass(frozen=True)
class Grant:
    """What one role may do: publish, subscribe, query and serve queryables on key expressions
    (under ``cellsim/<any cell>/``), hold liveliness tokens and watch them."""

    publish: tuple[str, ...] = ()
    subscribe: tuple[str, ...] = ()
    query: tuple[str, ...] = ()
    serve: tuple[str, ...] = ()
    token: tuple[str, ...] = ()
    watch_alive: bool = False
    other_keys: tuple[str, ...] = ()
    """Keys outside ``cellsim/`` the role publishes (the ROS joint state, whose key is the ROS topic's)."""


_WATCH = ("twin/**", "status/**", "diagnostics/**", "physical/**")
ROS_JOINT_STATE_KEYS = ("joint_states", "*/joint_states")
"""The keys outside ``cellsim/`` a bridge may publish a robot's ROS joint state on: ``joint_states`` under no or
one namespace (``**/joint_states`` let it publish ``cellsim/<cell>/command/joint_states``, the twin's)."""

GRANTS: dict[str, Grant] = {
    "twin": Grant(
        publish=("twin/**", "status/**", "command/**"), subscribe=("physical/**",),
        serve=("control/twin_mode", "describe"), token=("alive/twin",),
    ),
    "bridge": Grant(
        publish=("physical/**", "diagnostics/**", "controller/*/request"),
        subscribe=("command/**", "twin/*/twin_mode", "controller/*/state"),
        token=("alive/bridge",), watch_alive=True, other_keys=ROS_JOINT_STATE_KEYS,
    ),
    "emulator": Grant(
        publish=("physical/**", "controller/*/state", "status/emulator"),
        subscribe=("command/**", "controller/*/request"),
        serve=("control/fault",), token=("alive/emulator",),
    ),
    "robot": Grant(publish=("controller/*/state",), subscribe=("controller/*/request",), token=("alive/robot",)),
    "engineer": Grant(subscribe=_WATCH, query=("control/twin_mode", "control/fault", "describe"), watch_alive=True),
    "observer": Grant(subscribe=_WATCH, query=("describe",), watch_alive=True),
}
"""What each role may do. The twin's session is usually the router itself, whose own
operations are not remote ones; its grant serves a twin connected to another router, which must
hold the twin's certificate too (only it may serve TLS: :mod:`cellsim.live.pki`)."""


def access_control(grants: dict[str, Grant] = GRANTS) -> dict:
    """The Zenoh ``access_control`` configuration for ``grants``: default deny, subjects by common name."""
    rules, policies = [], []
    for role, grant in grants.items():
        ids = []

        def rule(flows, messages, keys, what):
            if not keys:
                return
            rule_id = f"{role}: {what}"
            rules.append({"id": rule_id, "permission": "allow", "flows": flows, "messages": messages,
                          "key_exprs": list(keys)})
            ids.append(rule_id)

        published = [f"{ANY_CELL}/{k}" for k in grant.publish] + list(grant.other_keys)
        subscribed = [f"{ANY_CELL}/{k}" for k in grant.subscribe]
        queried = [f"{ANY_CELL}/{k}" for k in grant.query]
        served = [f"{ANY_CELL}/{k}" for k in grant.serve]
        # a publisher learns who subscribes (it sends only what someone wants)
        rule(["ingress"], ["put"], published, "publishes")
        rule(["egress"], ["declare_subscriber"], published, "learns its subscribers")
        rule(["ingress"], ["declare_subscriber"], subscribed, "subscribes")
        rule(["egress"], ["put"], subscribed, "receives")
        rule(["ingress"], ["query"], queried, "asks")
        rule(["egress"], ["declare_queryable", "reply"], queried, "is answered")
        rule(["ingress"], ["declare_queryable", "reply"], served, "answers")
        rule(["egress"], ["query"], served, "is asked")
        rule(["ingress"], ["liveliness_token"], [f"{ANY_CELL}/{k}" for k in grant.token], "is alive")
        if grant.watch_alive:
            rule(["ingress"], ["declare_liveliness_subscriber", "liveliness_query"], [f"{ANY_CELL}/alive/**"],
                 "watches who is alive")
            rule(["egress"], ["liveliness_token", "reply"], [f"{ANY_CELL}/alive/**"], "sees who is alive")
        policies.append({"rules": ids, "subjects": [role]})
    subjects = [{"id": role, "cert_common_names": [role]} for role in grants]
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}
