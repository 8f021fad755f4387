"""Serve an emulated device over a pty pair, a loopback TCP socket or a python-can bus.

Each server runs the device in a daemon thread and is a context manager::

    with TCPServer(SDH2Emulator()) as srv:
        hand = SDH2(serial.serial_for_url(srv.url, timeout=0.05))

    with PtyServer(DSACON32mEmulator()) as srv:
        tactile = DSACON32m(serial.serial_for_url(srv.path, baudrate=115200))

    with CANServer(SDH2Emulator(), channel="sdh") as srv:
        hand = SDH2.over_can(can.Bus(interface="virtual", channel="sdh"))

A device is any object with ``feed(bytes) -> bytes`` (answer requests), ``poll() ->
bytes`` (bytes it pushes on its own, e.g. streamed frames), ``reset()`` (a new
connection) and a ``faults`` plan whose ``disconnect`` flag asks the server to drop the
connection.
"""

from __future__ import annotations

import errno
import os
import select
import socket
import threading
import time

__all__ = ["TCPServer", "PtyServer", "CANServer"]

_TICK = 0.004  # s: how often a server polls for input and pushed data


class _Server:
    def __init__(self, device):
        self.device = device
        self._stop = threading.Event()
        self._thread = None
        self.error = None

    def start(self):
        self._thread = threading.Thread(target=self._guarded, name=type(self).__name__, daemon=True)
        self._thread.start()
        return self

    def _guarded(self):
        try:
            self._run()
        except Exception as exc:  # kept for tests to inspect; a server must not die silently
            self.error = exc

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def __enter__(self):
        if self._thread is None:
            self.start()
        return self

    def __exit__(self, *exc):
        self.close()


class TCPServer(_Server):
    """The device behind a TCP port on the loopback interface (one client at a time).

    Parameters
    ----------
    device : emulator
    host : str
        Address to listen on (default 127.0.0.1).
    port : int
        0 picks a free port; see :attr:`url`.
    """

    def __init__(self, device, *, host: str = "127.0.0.1", port: int = 0):
        super().__init__(device)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.bind((host, port))
        self._sock.listen(1)
        self.host, self.port = self._sock.getsockname()[:2]

    @property
    def url(self) -> str:
        """pyserial URL of the server: ``socket://127.0.0.1:PORT``."""
        return f"socket://{self.host}:{self.port}"

    def _run(self):
        try:
            while not self._stop.is_set():
                r, _, _ = select.select([self._sock], [], [], 0.05)
                if not r:
                    continue
                conn, _ = self._sock.accept()
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self.device.reset()
                try:
                    self._serve(conn)
                finally:
                    conn.close()
        finally:
            self._sock.close()

    def _serve(self, conn):
        while not self._stop.is_set():
            r, _, _ = select.select([conn], [], [], _TICK)
            out = b""
            if r:
                try:
                    data = conn.recv(4096)
                except OSError:
                    return
                if not data:
                    return
                out = self.device.feed(data)
            out += self.device.poll()
            if out:
                try:
                    conn.sendall(out)
                except OSError:
                    return
            if self.device.faults.disconnect:
                self.device.faults.disconnect = False
                conn.shutdown(socket.SHUT_RDWR)
                return


class PtyServer(_Server):
    """The device on the master side of a pseudo-terminal pair; clients open :attr:`path`.

    The slave side is put in raw mode. A ``disconnect`` fault closes the master, after
    which the client's reads fail as on an unplugged USB adapter.
    """

    def __init__(self, device):
        super().__init__(device)
        import tty

        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)

    def _run(self):
        try:
            while not self._stop.is_set():
                r, _, _ = select.select([self._master], [], [], _TICK)
                out = b""
                if r:
                    try:
                        data = os.read(self._master, 4096)
                    except OSError as exc:
                        if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                            continue
                        if exc.errno == errno.EIO:  # no client has the slave open right now
                            time.sleep(_TICK)
                            continue
                        raise
                    out = self.device.feed(data)
                out += self.device.poll()
                if out:
                    self._write(out)
                if self.device.faults.disconnect:
                    self.device.faults.disconnect = False
                    os.close(self._master)
                    self._master = None
                    os.close(self._slave)
                    self._slave = None
                    return
        finally:
            for fd in (self._master, self._slave):
                if fd is not None:
                    try:
                        os.close(fd)
                    except OSError:
                        pass

    def _write(self, data: bytes):
        end = time.monotonic() + 1.0
        view = memoryview(data)
        while view and not self._stop.is_set() and time.monotonic() < end:
            try:
                n = os.write(self._master, view)
                view = view[n:]
            except BlockingIOError:
                time.sleep(_TICK)  # the client is not reading: drop after a second


class CANServer(_Server):
    """The device on a python-can bus: requests on ``rx_id`` (42), replies on ``tx_id`` (43).

    Parameters
    ----------
    device : emulator
    channel : str
        Channel name (for ``interface="virtual"``: any shared name).
    interface : str
        python-can interface (default ``"virtual"``; a vcan0 socketcan channel also works).
    bus : can.BusABC, optional
        An already-open bus to use instead.

    A ``disconnect`` fault silences the device for good (CAN has no connection to drop).
    """

    def __init__(self, device, *, channel: str = "touchloc", interface: str = "virtual",
                 rx_id: int = 42, tx_id: int = 43, bus=None):
        super().__init__(device)
        import can

        self._own = bus is None
        self.bus = bus or can.Bus(interface=interface, channel=channel)
        self.channel = channel
        self.rx_id = rx_id
        self.tx_id = tx_id

    def _run(self):
        import can

        try:
            while not self._stop.is_set():
                msg = self.bus.recv(timeout=_TICK)
                out = b""
                if (msg is not None and msg.arbitration_id == self.rx_id and not msg.is_extended_id
                        and not msg.is_remote_frame and not msg.is_error_frame):
                    out = self.device.feed(bytes(msg.data[:msg.dlc]))
                out += self.device.poll()
                for i in range(0, len(out), 8):
                    self.bus.send(can.Message(arbitration_id=self.tx_id, data=out[i:i + 8], is_extended_id=False))
                if self.device.faults.disconnect:
                    self.device.faults.disconnect = False
                    self.device.faults.silent = True
        finally:
            if self._own:
                self.bus.shutdown()
