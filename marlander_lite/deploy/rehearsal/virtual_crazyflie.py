"""A test double of ``cflib.crazyflie.Crazyflie`` whose radio is a :class:`VirtualFirmware`.

Only the connection manager is replaced. Everything the deployment calls is cflib's own code
running on this object: ``Commander``, ``HighLevelCommander``, ``Localization``/``Extpos``,
``Supervisor`` and ``Param`` (TOC download, value reads, confirmed writes) build real CRTP packets and call
:meth:`VirtualCrazyflie.send_packet`, which hands them to the firmware model; the firmware's
replies come back through a dispatcher thread to the port callbacks cflib registered, as
cflib's own incoming-packet thread does. ``SyncCrazyflie`` and ``Swarm`` are used unchanged:
:class:`VirtualCfFactory` is the ``factory`` argument ``Swarm`` documents for test doubles.

The connection sequence mirrors ``Crazyflie.open_link`` minus the log TOC and memories: request
-> parameter TOC -> ``connected`` -> all parameter values -> ``fully_connected``.
``close_link`` sends the zero-thrust setpoint that cflib sends when a link closes (it stops
the motors of a flying Crazyflie). :meth:`VirtualCrazyflie.fail_link` simulates a lost radio
link the way cflib reports one (``disconnected`` then ``connection_lost``).
"""

from __future__ import annotations

import collections
import datetime
import queue
import tempfile
import threading
from collections.abc import Callable

from cflib.crazyflie.commander import Commander
from cflib.crazyflie.extpos import Extpos
from cflib.crazyflie.high_level_commander import HighLevelCommander
from cflib.crazyflie.localization import Localization
from cflib.crazyflie.param import Param
from cflib.crazyflie.supervisor import Supervisor
from cflib.crazyflie.syncCrazyflie import SyncCrazyflie
from cflib.crazyflie.toccache import TocCache
from cflib.crtp.crtpstack import CRTPPacket, CRTPPort
from cflib.utils.callbacks import Caller

from marlander_lite.deploy.rehearsal.virtual_firmware import PROTOCOL_VERSION, VirtualFirmware


class _Platform:
    """The part of ``PlatformService`` that cflib's subsystems ask: the protocol version."""

    def __init__(self, version: int) -> None:
        self._version = version

    def get_protocol_version(self) -> int:
        return self._version


class _RadioLink:
    """Stands for an open link (cflib checks ``cf.link`` for truth and whether it resends)."""

    needs_resending = False

    def __init__(self, uri: str) -> None:
        self.uri = uri


class VirtualCrazyflie:
    """A ``cflib.crazyflie.Crazyflie`` double whose packets go to ``firmware``.

    Attributes used by cflib's subsystems and ``SyncCrazyflie``: the ``Caller`` s
    (``connected``, ``disconnected``, ...), ``link``, ``link_uri``, ``platform``,
    ``send_packet``, ``add_port_callback``/``remove_port_callback``. ``sent`` records the last
    packets as ``(port, channel, bytes)`` for tests.
    """

    def __init__(self, firmware: VirtualFirmware, protocol_version: int = PROTOCOL_VERSION) -> None:
        self.firmware = firmware
        for name in (
            "disconnected",
            "connection_lost",
            "link_established",
            "connection_requested",
            "connected",
            "fully_connected",
            "connection_failed",
            "packet_received",
            "packet_sent",
        ):
            setattr(self, name, Caller())
        self.link: _RadioLink | None = None
        self.link_uri = ""
        self.connected_ts: datetime.datetime | None = None
        self.platform = _Platform(protocol_version)
        self.sent: collections.deque[tuple[int, int, bytes]] = collections.deque(maxlen=10_000)
        self._callbacks: list[tuple[int, Callable[[CRTPPacket], None]]] = []
        self._inbox: queue.Queue[CRTPPacket | None] = queue.Queue()
        self._dispatcher: threading.Thread | None = None
        self._send_lock = threading.Lock()
        self._toc_dir: tempfile.TemporaryDirectory[str] | None = None  # cflib caches TOCs here while a link is open
        self.commander = Commander(self)
        self.high_level_commander = HighLevelCommander(self)
        self.loc = Localization(self)
        self.extpos = Extpos(self)
        self.param = Param(self)
        self.supervisor = Supervisor(self)
        self.param.all_updated.add_callback(lambda: self.fully_connected.call(self.link_uri))

    # ------------------------------------------------------------------ cflib's Crazyflie interface
    def open_link(self, link_uri: str) -> None:
        self.connection_requested.call(link_uri)
        self.link_uri = link_uri
        self.link = _RadioLink(link_uri)
        self._dispatcher = threading.Thread(target=self._dispatch, name=f"virtual-cf-{link_uri}", daemon=True)
        self._dispatcher.start()
        self.link_established.call(link_uri)
        if self._toc_dir is None:
            self._toc_dir = tempfile.TemporaryDirectory(prefix="marlander-virtual-cf-", ignore_cleanup_errors=True)
        self.param.refresh_toc(self._param_toc_updated, TocCache(rw_cache=self._toc_dir.name))

    def _param_toc_updated(self) -> None:
        self.connected_ts = datetime.datetime.now()
        self.connected.call(self.link_uri)
        self.param.request_update_of_all_params()

    def close_link(self) -> None:
        if self.link is not None:
            self.commander.send_setpoint(0, 0, 0, 0)  # as cflib does: zero thrust, motors off
        self._drop_link()
        self.disconnected.call(self.link_uri)

    def fail_link(self, message: str = "Too many packets lost") -> None:
        """Simulate a lost radio link: nothing reaches the firmware any more; cflib's callbacks fire."""
        if self.link is None:
            return
        self._drop_link()
        self.disconnected.call(self.link_uri)
        self.connection_lost.call(self.link_uri, message)

    def _drop_link(self) -> None:
        self.link = None
        self.connected_ts = None
        if self._dispatcher is not None:
            self._inbox.put(None)
            if self._dispatcher is not threading.current_thread():
                self._dispatcher.join(timeout=1.0)
            self._dispatcher = None
        if self._toc_dir is not None:  # removed with the link, not left to the garbage collector
            self._toc_dir.cleanup()
            self._toc_dir = None

    def is_connected(self) -> bool:
        return self.connected_ts is not None

    def add_port_callback(self, port: int, cb: Callable[[CRTPPacket], None]) -> None:
        self._callbacks.append((port, cb))

    def remove_port_callback(self, port: int, cb: Callable[[CRTPPacket], None]) -> None:
        if (port, cb) in self._callbacks:
            self._callbacks.remove((port, cb))

    def is_called_by_incoming_handler_thread(self) -> bool:
        return threading.current_thread() is self._dispatcher

    def send_packet(self, pk: CRTPPacket, expected_reply: tuple = (), resend: bool = False, timeout: float = 0.2):
        """Deliver ``pk`` to the firmware at once (a link that never loses packets needs no resending)."""
        if not pk.is_data_size_valid():
            raise ValueError(f"CRTP payload of {pk.get_data_size()} bytes exceeds {CRTPPacket.MAX_DATA_SIZE}.")
        with self._send_lock:
            if self.link is None:
                return  # like cflib: packets to a closed link are dropped
            self.sent.append((pk.port, pk.channel, bytes(pk.data)))
            for reply in self.firmware.receive(pk):
                self._inbox.put(reply)
        self.packet_sent.call(pk)

    def _dispatch(self) -> None:
        while True:
            pk = self._inbox.get()
            if pk is None:
                return
            self.packet_received.call(pk)
            for port, cb in list(self._callbacks):
                if port in (pk.port, CRTPPort.ALL):
                    cb(pk)


class VirtualCfFactory:
    """``Swarm(uris, factory=VirtualCfFactory(firmwares))``: one ``SyncCrazyflie`` per URI on a virtual Crazyflie.

    Args:
        firmwares: URI -> the :class:`VirtualFirmware` of that drone.
    """

    def __init__(self, firmwares: dict[str, VirtualFirmware]) -> None:
        self.firmwares = firmwares
        self.crazyflies: dict[str, VirtualCrazyflie] = {}
        """URI -> the virtual Crazyflie built for it (for fault injection)."""

    def construct(self, uri: str) -> SyncCrazyflie:
        if uri not in self.firmwares:
            raise ValueError(f"No simulated Crazyflie at {uri!r}; simulated URIs: {sorted(self.firmwares)}.")
        cf = VirtualCrazyflie(self.firmwares[uri])
        self.crazyflies[uri] = cf
        return SyncCrazyflie(uri, cf=cf)
