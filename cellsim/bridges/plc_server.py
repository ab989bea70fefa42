"""The emulated PLC: an OPC UA server holding the nodes the bridge configuration names.

``cellsim emulate --opcua`` (with ``--bridge``) serves the configuration's ``plc``
nodes on its endpoint (``--opcua PORT`` overrides the port), as the PLC would:
each entity of the PLC writes its sample's fields to its nodes at the PLC's scan
(``SCAN``, coded as ``cellsim.bridges.opcua`` says, stamped with the scan's time), the
heartbeat node counts the scans, and under the twin's command (``--commanded-by-twin``) the command nodes a
client writes become the entity's commands, taken only when the client's command
heartbeat moved (the PLC's program's own watchdog: a lost daemon's commands stop,
and the entity's command source fails safe after its ``stale_after``). An entity
whose command nodes hold no value is not commanded by the twin (released); a
command node holding a value its field cannot take reads as the kind's safe value.

The certificate check is asyncua's: it validates the client certificate a session
presents when it is created (``CreateSession``), against the bridge's.

Security as the daemon's: Basic256Sha256 Sign & Encrypt with the PLC's OPC UA
certificate, accepting only the bridge's (``security: none``: no security).
Faults, as the entity's outlet (``--fault welder=KIND``): ``bad_status`` (its
nodes carry BadSensorFailure), ``freeze`` (the PLC's scan stops: the heartbeat
and every node hold still).
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from datetime import datetime, timezone

from cellsim import codec
from cellsim.bridges.opcua import (APPLICATION_URI, NodeValueError, from_node, pinned, quiet_asyncua, to_node,
                                   variant_type)

SCAN = 0.01
"""The emulated PLC's scan (s): how often its heartbeat counts and its outputs are written."""
PLC_FAULTS = ("bad_status", "freeze")
log = logging.getLogger("cellsim.plc")


class EmulatedPlc:
    """An OPC UA server on its own thread and asyncio loop, holding one PLC's nodes."""

    def __init__(self, settings, samples: dict, commands: dict, safe: dict, endpoint: str | None = None,
                 certificates: tuple | None = None):
        """``samples``/``commands``: entity -> FieldCodec; ``certificates``: (the PLC's certificate, its key, the
        bridge's certificate), needed unless ``settings.security`` is none."""
        self.settings, self.safe = settings, safe
        quiet_asyncua()
        self.endpoint = endpoint or settings.endpoint
        self.certificates = certificates
        self.types = {e: dict(zip(samples[e].names, samples[e].types)) for e in settings.entities}
        self.command_types = {e: dict(zip(commands[e].names, commands[e].types))
                              for e, m in settings.entities.items() if m.commands}
        self.sources: dict = {}
        """Entity -> its command source (a ``ZenohCommandSource``), under the twin's command."""
        self._pending: dict[str, dict] = {}  # entity -> fields to write at the next scan
        self._faults: dict[str, str | None] = {}
        self._commands: dict[str, object] = {}  # node id text -> its latest written value
        self._command_heartbeat = None
        self._seq = 0
        self._lock = threading.Lock()
        self.scans = 0
        self.commands_taken = 0
        self._ready = threading.Event()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=lambda: asyncio.run(self._serve()), name="opcua-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(30.0) or self._error is not None:
            self.close()
            raise OSError(f"cannot serve OPC UA on {self.endpoint}: {self._error or 'it did not start'}")

    # -- the emulator's side --------------------------------------------------------------------
    def outlet(self, entity: str) -> "PlcOutlet":
        return PlcOutlet(self, entity)

    def publish(self, entity: str, fields: dict, fault: str | None) -> int:
        """The entity's sample, written at the next scan (as ``fault`` makes of it)."""
        with self._lock:
            self._pending[entity] = dict(fields)
            self._faults[entity] = fault
        return 1

    # -- the server -------------------------------------------------------------------------------
    async def _serve(self) -> None:
        from asyncua import Server, ua

        settings = self.settings
        try:
            users = None
            if settings.security != "none":  # a session only for the channel that shows the bridge's certificate
                from asyncua.server.user_managers import CertificateUserManager

                users = CertificateUserManager()  # asyncua's: the secure channel's peer certificate, byte for byte
                await users.add_user(self.certificates[2], "bridge", format="pem")
            server = Server(user_manager=users)
            await server.init()
            server.set_endpoint(self.endpoint)
            server.set_server_name("cellsim emulated PLC")
            await server.set_application_uri(APPLICATION_URI["plc"])
            if settings.security != "none":
                from cellsim.bridges.opcua import load_certificate

                certificate, key, client = self.certificates
                server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
                await server.load_certificate(str(certificate), format="pem")
                await server.load_private_key(str(key), format="pem")
                server.set_certificate_validator(pinned(load_certificate(client)))
            else:
                server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
            nodes = {}

            async def variable(text: str, value, kind, writable: bool = False):
                node_id = ua.NodeId.from_string(text)
                while len(await server.get_namespace_array()) <= node_id.NamespaceIndex:
                    await server.register_namespace(f"urn:cellsim:plc:{len(await server.get_namespace_array())}")
                node = await server.nodes.objects.add_variable(node_id, text.rsplit("=", 1)[-1], ua.Variant(value, kind))
                if writable:
                    await node.set_writable()
                nodes[node_id.to_string()] = node
                return node

            heartbeat = await variable(settings.heartbeat, 0, ua.VariantType.Int32)
            await variable(settings.command_heartbeat, 0, ua.VariantType.Int32, writable=True)
            fields = {}
            for entity, mapping in settings.entities.items():
                for name, text in mapping.fields.items():
                    ctype = self.types[entity][name]
                    fields[(entity, name)] = await variable(text, to_node(ctype, None if ctype.kind != "bool" else False),
                                                            variant_type(ctype))
                for name, text in mapping.commands.items():
                    ctype = self.command_types[entity][name]
                    await variable(text, to_node(ctype, self.safe[entity][name]), variant_type(ctype), writable=True)
            commanded = [nodes[ua.NodeId.from_string(t).to_string()]
                         for m in settings.entities.values() for t in [*m.commands.values()]]
            commanded.append(nodes[ua.NodeId.from_string(settings.command_heartbeat).to_string()])
            async with server:
                watch = await server.create_subscription(SCAN * 1000.0, _Writes(self))
                await watch.subscribe_data_change(commanded, queuesize=1, sampling_interval=0)
                self._ready.set()
                count = 0
                while not self._stop.is_set():
                    with self._lock:
                        pending, faults = dict(self._pending), dict(self._faults)
                    if "freeze" not in faults.values():
                        count += 1
                        scan = datetime.now(timezone.utc)  # as a PLC stamps its values: once per scan
                        await heartbeat.write_value(ua.DataValue(ua.Variant(count, ua.VariantType.Int32),
                                                                 SourceTimestamp=scan))
                        for (entity, name), node in fields.items():
                            if entity not in pending:
                                continue
                            ctype = self.types[entity][name]
                            value = ua.Variant(to_node(ctype, pending[entity].get(name)), variant_type(ctype))
                            status = ua.StatusCode(ua.StatusCodes.BadSensorFailure if faults.get(entity) == "bad_status"
                                                   else ua.StatusCodes.Good)
                            await node.write_value(ua.DataValue(value, StatusCode=status, SourceTimestamp=scan))
                        self.scans += 1
                    await asyncio.sleep(SCAN)
        except BaseException as e:  # noqa: BLE001 - said to the constructor, or logged once running
            if not self._ready.is_set():
                self._error = e
                self._ready.set()
            elif not isinstance(e, asyncio.CancelledError):
                log.error("the emulated PLC stopped: %s", e)

    def _written(self, node: str, value) -> None:
        """A client wrote a command node (on the server's loop)."""
        from asyncua import ua

        if node != ua.NodeId.from_string(self.settings.command_heartbeat).to_string():
            self._commands[node] = value
            return
        if value == self._command_heartbeat:
            return
        self._command_heartbeat = value
        for entity, types in self.command_types.items():
            source = self.sources.get(entity)
            if source is None:
                continue
            fields, released = {}, True
            for name, text in self.settings.entities[entity].commands.items():
                written = self._commands.get(ua.NodeId.from_string(text).to_string())
                try:
                    fields[name] = from_node(types[name], written, nullable=True)
                except NodeValueError:
                    fields[name] = self.safe[entity][name]  # a value the device cannot take: its safe one
                released = released and (fields[name] is None or types[name].kind == "bool")
            if released:
                continue  # no value in any command node: the twin does not command it (its source goes stale)
            self._seq += 1
            self.commands_taken += 1
            source.deliver(codec.encode_fields(time.time(), self._seq, {**self.safe[entity], **fields}))

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=10.0)


class _Writes:
    """The server's own subscription to its command nodes: what clients wrote."""

    def __init__(self, plc: EmulatedPlc):
        self.plc = plc

    def datachange_notification(self, node, value, data) -> None:
        self.plc._written(node.nodeid.to_string(), value)


class PlcOutlet:
    """An entity's samples as the emulated PLC's nodes."""

    faults = PLC_FAULTS

    def __init__(self, plc: EmulatedPlc, entity: str):
        self.plc, self.entity = plc, entity

    def send(self, fields: dict, fault: str | None, sim_time: float) -> int:
        return self.plc.publish(self.entity, fields, fault)
