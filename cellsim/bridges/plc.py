"""A PLC over OPC UA beside the twin: the entities wired to it in, the twin's commands to them out.

The daemon is an OPC UA client of the PLC (``plc.endpoint``), with Sign & Encrypt
(Basic256Sha256) and the cell's OPC UA certificates by default
(``cellsim.bridges.opcua``). It subscribes to the PLC's heartbeat and to every
node of the configured entities' samples at the ``publishing_interval``; an
asyncio loop on a thread of its own only hands each notification to the daemon's
inbox, and the daemon's thread judges it (``PlcLink.take``), by the link rule
(``cellsim.link``) per entity:

* a node whose value comes with a bad status code (the PLC's own verdict on its
  input: a wire break, a module fault): the entity is *corrupt*;
* a value the field cannot take (a code outside its list, a non-finite number):
  *range*;
* the PLC's heartbeat, a counter its program increments every scan, must move
  (any change counts, so a restarted PLC or a counter that wraps is heard at once):
  a repeat is refused, and with no movement for ``watchdog`` (a stopped PLC, a lost
  connection, a frozen subscription) every entity of the PLC is *stale* (timeout);
  a heartbeat with a bad status code, or not an integer, fails every entity.

Each entity node is monitored with a queue (``QUEUE_SIZE``), so every value the PLC
takes between two publishes reaches the daemon, not only the last: a light curtain's
break shorter than the publishing interval is published, broken then clear (the twin's
entity, taking the newest sample at each of its updates, may still not act on it). The
values of one publish are handed over in the order the PLC took them
(:class:`PublishInOrder`). The heartbeat keeps only its latest value: it says the PLC
scans, once per publish; a bad heartbeat fails every entity, and no value is trusted
until the heartbeat moves good again.

Every movement of the heartbeat counts as a good message for each entity whose
nodes are all good (its sample is published, so the twin's entity stays fresh at
the publishing interval), and a changed value is published at once. A lost
connection is dialled again every ``reconnect_after`` seconds.

In twin mode the entity's command nodes are written every ``command_cycle_time``
and at once when the twin's command changes, with the daemon's own heartbeat
node counting up; when the twin is lost, the kind's safe command is written.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
from dataclasses import dataclass, field

from cellsim import codec
from cellsim.bridges.opcua import (APPLICATION_URI, NodeValueError, from_node, pinned, quiet_asyncua, to_node,
                                   variant_type)
from cellsim.link import Fault, LinkTrust, PhysicalLink
from cellsim.live import keys

log = logging.getLogger("cellsim.bridge")
PLC_FAULTS = (Fault.CORRUPT, Fault.REPEATED, Fault.RANGE, Fault.TIMEOUT)
HEARTBEAT = "heartbeat"
"""The inbox's name for the PLC's heartbeat node."""
NEW_SESSION = "new session"
"""The inbox's word that a new connection to the PLC begins: what the entity nodes held before it is forgotten, so a
scan heard on the new connection before its first values publishes nothing from before the outage."""
QUEUE_SIZE = 64
"""Values the PLC keeps per entity node between two publishes (the oldest dropped past it): a PLC scanning every
millisecond with a 20 ms publishing interval takes at most 20 (a server may keep fewer: it revises the size)."""


@dataclass
class PlcEntityLink:
    """One entity wired to the PLC: its nodes' latest values, their statuses and its link's trust."""

    entity: str
    types: dict
    """Sample field -> its ChannelType."""
    trust: LinkTrust
    publisher: object
    values: dict = field(default_factory=dict)
    bad: set = field(default_factory=set)
    """Fields whose node's latest value came with a bad status code."""
    seq: int = 0
    published: int = 0
    failures_published: int = 0
    diagnostics: object = None
    received: int = 0


class PlcLink:
    """The daemon's side of one PLC (notifications in, command nodes out)."""

    def __init__(self, cell: str, settings, session, samples: dict, commands: dict, safe: dict, inbox,
                 recover_after: int = 3, certificates: tuple | None = None):
        """``samples``/``commands``: entity -> its FieldCodec; ``certificates``: (the bridge's certificate, its key,
        the PLC's certificate) files, needed unless ``settings.security`` is none."""
        from cellsim.bridges.diagnostics import DeviceDiagnostics

        self.settings, self.inbox, self.safe = settings, inbox, safe
        quiet_asyncua()
        self.certificates = certificates
        self.commands = {e: commands[e] for e, m in settings.entities.items() if m.commands}
        self.entities: dict[str, PlcEntityLink] = {}
        self._node_field: dict[str, tuple[str, str]] = {}  # node id text -> (entity, field)
        for entity, mapping in settings.entities.items():
            codec_ = samples[entity]
            link = PlcEntityLink(entity, dict(zip(codec_.names, codec_.types)),
                                 LinkTrust(timeout=settings.watchdog, recover_after=recover_after, max_gap=1 << 62,
                                           faults=PLC_FAULTS),
                                 session.declare_publisher(keys.physical(cell, entity)))
            link.diagnostics = DeviceDiagnostics(entity, "PLC", link.trust, 1.0 / settings.publishing_interval,
                                                 session.declare_publisher(keys.diagnostics(cell, entity)))
            self.entities[entity] = link
            for name, node in mapping.fields.items():
                self._node_field[_canonical(node)] = (entity, name)
        self.heartbeat = LinkTrust(timeout=settings.watchdog, recover_after=1, max_gap=1 << 62, faults=PLC_FAULTS)
        self._last_heartbeat = None
        self.connected = False
        self.connections = 0
        self.writes = 0
        self.safe_writes = 0
        self._heartbeat_out = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._client = None
        self._writing: asyncio.Lock | None = None  # one write at a time (made on the loop)
        self._pending: dict[str, list] = {}
        """Entity -> its newest command not yet written (node, value, type): a newer one replaces it."""
        self._pending_lock = threading.Lock()
        self._draining = False  # a drain of ``_pending`` is scheduled or running on the loop
        self.refused: set[str] = set()
        """Entities whose last command the PLC refused (a node it would not take): while any is, no heartbeat."""
        self._age = 0.0  # how long ago the notification being taken arrived (s): :meth:`take`
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="opcua-plc", daemon=True)

    def start(self) -> None:
        self._thread.start()

    # -- in (the daemon's thread) ----------------------------------------------------------
    def take(self, node: str, value, good: bool, now: float, age: float = 0.0) -> None:
        """One notification: the PLC's heartbeat, or a node of an entity's sample, with its status; ``now``: when it
        arrived (the daemon's clock), ``age`` (s) how long ago that was, so what it publishes is stamped then."""
        self._age = age
        try:
            self._take(node, value, good, now)
        finally:
            self._age = 0.0

    def _wall(self) -> float:
        """The wall-clock time the notification being taken arrived (now, outside :meth:`take`)."""
        return time.time() - self._age

    def _take(self, node: str, value, good: bool, now: float) -> None:
        if node == NEW_SESSION:
            for link in self.entities.values():
                link.values.clear()
                link.bad.clear()
            return
        if node == HEARTBEAT:
            if not good or isinstance(value, bool) or not isinstance(value, int):
                fault = Fault.CORRUPT if not good else Fault.RANGE
                self.heartbeat.fail(fault, now)  # no value is judged until the scan is heard good again
                for link in self.entities.values():  # the PLC's own scan counter is bad: nothing of it is trusted
                    self._fail(link, fault, now)
                return
            if value == self._last_heartbeat:
                self.heartbeat.fail(Fault.REPEATED)  # counted: the PLC's scan did not move
                return
            self._last_heartbeat = value  # any change is a scan: a restarted PLC or a counter that wraps included
            self.heartbeat.good(now)
            for link in self.entities.values():
                link.received += 1
                link.diagnostics.frame()
                self._judge(link, now)
            return
        entity, name = self._node_field[node]
        link = self.entities[entity]
        link.received += 1
        link.diagnostics.frame()
        if not good:
            link.bad.add(name)
            self._fail(link, Fault.CORRUPT, now)
            return
        link.bad.discard(name)
        try:
            decoded = from_node(link.types[name], value)
        except NodeValueError as e:
            log.warning("%s.%s from the PLC: %s", entity, name, e)
            link.values.pop(name, None)
            self._fail(link, Fault.RANGE, now)
            return
        changed = link.values.get(name) != decoded
        link.values[name] = decoded
        if changed and self._alive(now):
            self._judge(link, now)

    def _alive(self, now: float) -> bool:
        """The PLC's scan heard moving, good, within the watchdog (and not bad since)."""
        heartbeat = self.heartbeat
        return (heartbeat.link is PhysicalLink.OK and heartbeat.last_good is not None
                and now - heartbeat.last_good <= self.settings.watchdog)

    def _judge(self, link: PlcEntityLink, now: float) -> None:
        if link.bad or len(link.values) != len(link.types):
            return  # a bad or missing node: failed already, or not yet heard
        link.seq += 1
        judgement = link.trust.receive(now, link.seq)
        if judgement.good:
            link.published += 1
            link.publisher.put(codec.encode_fields(self._wall(), link.seq, dict(link.values)))

    def _fail(self, link: PlcEntityLink, fault: Fault, now: float | None) -> None:
        link.trust.fail(fault, now)
        link.seq += 1
        link.failures_published += 1
        link.publisher.put(codec.encode_failure(self._wall(), link.seq, fault))

    def check_watchdog(self, now: float) -> None:
        for link in self.entities.values():
            judgement = link.trust.watchdog(now)
            if judgement is not None:
                link.seq += 1
                link.failures_published += 1
                link.publisher.put(codec.encode_failure(time.time(), link.seq, judgement.fault))

    def publish_diagnostics(self, now: float, every: float) -> None:
        for link in self.entities.values():
            link.diagnostics.publish(now, every)

    # -- out -------------------------------------------------------------------------------
    def send(self, entity: str, fields: dict | None) -> None:
        """Write the twin's command ``fields`` (None: the twin is lost, the kind's safe command) to the entity's
        command nodes, with the daemon's heartbeat; nothing while the PLC is not connected."""
        self.writes += 1
        if fields is None:
            self.safe_writes += 1
            fields = self.safe[entity]
        self._command(entity, {**self.safe[entity], **fields})

    def release(self, entity: str) -> None:
        """The twin does not command the entity (model or shadow mode): its command nodes hold no value (-1,
        NaN; a flag false), the heartbeat counting (the PLC program runs the device on its own)."""
        self._command(entity, None)

    def _command(self, entity: str, fields: dict | None) -> None:
        """Hand the entity's command to the loop's writer. Only the newest command of each entity waits to be written:
        a PLC slower to take a write than the command cycle gets the latest command one write late, never a backlog
        of old ones ahead of it (the twin's safe command among them), and the heartbeat moves only with it."""
        types = dict(zip(self.commands[entity].names, self.commands[entity].types))

        def value(name: str):
            if fields is None:  # released: no value (a flag has none: false)
                return False if types[name].kind == "bool" else to_node(types[name], None)
            return to_node(types[name], fields.get(name))

        values = [(node, value(name), variant_type(types[name]))
                  for name, node in self.settings.entities[entity].commands.items()]
        loop = self._loop
        if loop is None or not self.connected:
            return
        with self._pending_lock:
            self._pending.pop(entity, None)  # (the newest goes last: entities are written in the order they asked)
            self._pending[entity] = values
            if self._draining:
                return
            self._draining = True
        asyncio.run_coroutine_threadsafe(self._drain(), loop)

    async def _drain(self) -> None:
        """Write the waiting commands, each entity's newest, until none waits; the heartbeat counts one per write."""
        try:
            while True:
                with self._pending_lock:
                    if not self._pending:
                        self._draining = False
                        return
                    entity = next(iter(self._pending))
                    values = self._pending.pop(entity)
                self._heartbeat_out = (self._heartbeat_out + 1) % 2**31
                await self._write(entity, values, self._heartbeat_out)
        except BaseException:
            with self._pending_lock:  # (the loop is closing): a later command schedules a drain of its own
                self._draining = False
            raise

    async def _write(self, entity: str, values: list, heartbeat: int) -> None:
        """Write an entity's command nodes, then, only once the PLC took every one of them and every entity's last
        command, the daemon's heartbeat: OPC UA applies each node of a write on its own, so a refused node (its type,
        its range, its access) would otherwise leave an old command standing under a heartbeat that still counts.
        One write at a time, in the order asked: a heartbeat never overtakes the commands before it."""
        from asyncua import ua

        if self._writing is None:
            self._writing = asyncio.Lock()
        async with self._writing:
            client = self._client
            if client is None:
                return
            try:
                nodes = [client.get_node(node) for node, _, _ in values]
                await client.write_values(nodes, [ua.DataValue(ua.Variant(v, kind)) for _, v, kind in values])
            except Exception as e:  # noqa: BLE001 - a refused or lost write: said; the heartbeat stops
                if entity not in self.refused:
                    log.warning("PLC refused %s's command (%s): the daemon's heartbeat stops until it takes one", entity, e)
                self.refused.add(entity)
                return
            self.refused.discard(entity)
            if self.refused:
                return  # another entity's last command was refused: no heartbeat, the PLC's watchdog acts
            try:
                await client.write_values([client.get_node(self.settings.command_heartbeat)],
                                          [ua.DataValue(ua.Variant(heartbeat, ua.VariantType.Int32))])
            except Exception as e:  # noqa: BLE001 - a lost write: said; the PLC's own watchdog acts
                log.warning("PLC write failed: %s", e)

    # -- the connection (its own thread and asyncio loop) ---------------------------------------------
    def _run(self) -> None:
        asyncio.run(self._serve())

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        said = None
        while not self._stop.is_set():
            try:
                await self._session()
                said = None
            except Exception as e:  # noqa: BLE001 - any failure of the session: dial again
                if str(e) != said:
                    said = str(e)
                    log.warning("PLC at %s: %s: %s (dialling again every %g s)", self.settings.endpoint,
                                type(e).__name__, e, self.settings.reconnect_after)
            finally:
                self.connected, self._client = False, None
            await asyncio.get_running_loop().run_in_executor(None, self._stop.wait, self.settings.reconnect_after)

    async def _session(self) -> None:
        from asyncua import Client, ua

        settings = self.settings
        client = Client(settings.endpoint, timeout=2.0)
        client.application_uri = APPLICATION_URI["bridge"]
        if settings.security != "none":
            from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
            from asyncua.crypto.uacrypto import CertProperties

            from cellsim.bridges.opcua import load_certificate

            certificate, key, server = self.certificates
            await client.set_security(SecurityPolicyBasic256Sha256, CertProperties(str(certificate), "pem"),
                                      CertProperties(str(key), "pem"), server_certificate=CertProperties(str(server), "pem"),
                                      mode=ua.MessageSecurityMode.SignAndEncrypt)
            client.certificate_validator = pinned(load_certificate(server))
        put = self.inbox.put
        heartbeat = _canonical(settings.heartbeat)
        order = PublishInOrder(put, asyncio.get_running_loop())

        class Handler:
            def datachange_notification(self, node, value, data) -> None:  # on the loop: hand over, nothing more
                datum = data.monitored_item.Value
                good = datum.StatusCode is None or datum.StatusCode.is_good()
                name = node.nodeid.to_string()
                order.add(name, datum, ("plc", None, (HEARTBEAT if name == heartbeat else name, value, good),
                                        time.perf_counter()))

            def status_change_notification(self, status) -> None:
                log.warning("PLC subscription: %s", status)

        async with client:
            params = ua.CreateSubscriptionParameters(
                RequestedPublishingInterval=settings.publishing_interval * 1000.0,
                RequestedLifetimeCount=max(30, int(3 * settings.watchdog / settings.publishing_interval) * 3),
                RequestedMaxKeepAliveCount=max(1, int(settings.watchdog / settings.publishing_interval / 2)),
                MaxNotificationsPerPublish=0, PublishingEnabled=True, Priority=0)
            subscription = await client.create_subscription(params, Handler())
            # before any item is monitored: every notification of this connection comes after it in the inbox
            put(("plc", None, (NEW_SESSION, None, True), time.perf_counter()))
            watched = [heartbeat, *self._node_field]
            handles = await subscription.subscribe_data_change([client.get_node(heartbeat)], queuesize=1,
                                                               sampling_interval=0)
            handles += await subscription.subscribe_data_change([client.get_node(n) for n in self._node_field],
                                                                queuesize=QUEUE_SIZE, sampling_interval=0)
            for name, handle in zip(watched, handles):
                if not isinstance(handle, int):
                    raise RuntimeError(f"the PLC refused to monitor {name}: {handle}")
            self._client, self.connected = client, True
            self.connections += 1
            log.info("PLC at %s: subscribed to %d nodes every %g s (%s)", settings.endpoint, len(watched),
                     settings.publishing_interval, "signed and encrypted" if settings.security != "none" else "NO SECURITY")
            state = client.get_node(ua.ObjectIds.Server_ServerStatus_State)
            while not self._stop.is_set():  # a read every half watchdog: a lost PLC raises, and is dialled again
                await asyncio.sleep(settings.watchdog / 2)
                await asyncio.wait_for(state.read_value(), timeout=max(1.0, settings.watchdog))

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=10.0)


class PublishInOrder:
    """One publish's notifications, handed to ``put`` in the order the PLC took the values.

    A server lists a publish's values node by node. They are handed over sorted by their source timestamps (else the
    server's; the same stamp: as listed), so that no sample pairs one node's later value with another's earlier,
    while each node's own values keep the order the server lists them in, whatever their stamps say (a clock stepped
    back, a value stamped by the server where the one before was stamped by the PLC): only the interleaving of
    different nodes follows the stamps.

    asyncua calls its handler in a task per notification, all of one publish created before any of them runs: the
    hand-over, scheduled on ``loop`` by the first notification, runs after the last."""

    def __init__(self, put, loop):
        self.put, self.loop = put, loop
        self.publish: list[tuple[float, object]] = []
        self.latest: dict[str, float] = {}  # node -> the order key of its last value in this publish

    def add(self, node: str, datum, item) -> None:
        """A notification of ``node`` whose DataValue is ``datum``: ``item`` goes to ``put`` at the hand-over."""
        if not self.publish:
            self.loop.call_soon(self.hand_over)
        at = _seconds(datum.SourceTimestamp) or _seconds(datum.ServerTimestamp) or (
            self.publish[-1][0] if self.publish else 0.0)
        at = max(at, self.latest.get(node, -math.inf))
        self.latest[node] = at
        self.publish.append((at, item))

    def hand_over(self) -> None:
        self.publish.sort(key=lambda stamped: stamped[0])
        for _, item in self.publish:
            self.put(item)
        self.publish.clear()
        self.latest.clear()


def _seconds(stamp) -> float | None:
    """A DataValue's timestamp as seconds since 1970, or None for none (OPC UA's "no time" decodes as 1601)."""
    if stamp is None or stamp.year <= 1601:
        return None
    return stamp.timestamp()


def _canonical(node: str) -> str:
    """A node id as OPC UA prints it (how notifications name their node)."""
    from asyncua import ua

    return ua.NodeId.from_string(node).to_string()
