"""A socketcand server on 127.0.0.1 that bridges TCP clients to a python-can bus.

socketcand (https://github.com/linux-can/socketcand) exposes SocketCAN buses
over TCP with an ASCII protocol; python-can's ``socketcand`` interface is its
client. This server speaks the part of the protocol that client uses, so a host
in another process reaches an emulated drive exactly as it would reach a CAN
bus behind a socketcand daemon, without a kernel vcan device::

    server: < hi >
    client: < open can0 >            server: < ok >     (< error ... > for another bus name)
    client: < rawmode >              server: < ok >
    client: < send 601 8 40 0 10 0 0 0 0 0 >              (id hex, dlc, bytes hex)
    server: < frame 581 1712345678.123456 4300100092010200 >  (id, seconds.microseconds, data)

Standard identifiers are three hex digits, extended ones eight. Each client
gets its own endpoint on the bus, so clients see each other's frames as on a
real CAN bus, and never their own.
"""

from __future__ import annotations

import socket
import threading

import can

__all__ = ["SocketcandServer", "format_frame", "parse_command"]


def format_frame(msg: can.Message) -> bytes:
    """A received CAN frame as a socketcand ``< frame ... >`` line."""
    can_id = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    data = bytes(msg.data[: msg.dlc]).hex().upper()
    return f"< frame {can_id} {msg.timestamp:.6f} {data} >".encode("ascii")


def parse_command(text: str) -> list[str]:
    """``"< send 601 2 1 ff >"`` -> ``["send", "601", "2", "1", "ff"]``."""
    return text.strip()[1:-1].split()


class SocketcandServer:
    """Serve the python-can ``virtual`` channel ``channel`` to socketcand clients.

    Parameters
    ----------
    channel : str
        The virtual bus channel to bridge.
    bus_name : str
        Bus name clients ``open`` (what goes after the slash in the host's port).
    port : int
        TCP port on 127.0.0.1; 0 picks a free one (see :attr:`address`).
    """

    def __init__(self, channel: str, bus_name: str = "can0", port: int = 0):
        self.channel = channel
        self.bus_name = bus_name
        self._listener = socket.create_server(("127.0.0.1", port))
        self.port = self._listener.getsockname()[1]
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._clients: list[socket.socket] = []
        self._lock = threading.Lock()
        self.error: BaseException | None = None

    @property
    def address(self) -> str:
        """``"127.0.0.1:PORT/BUS"``: what goes in ``[device].port``, with ``[device.canopen]``
        ``can_interface = "socketcand"``."""
        return f"127.0.0.1:{self.port}/{self.bus_name}"

    def start(self) -> SocketcandServer:
        self._spawn(self._accept_loop, "socketcand-accept")
        return self

    def _spawn(self, target, name, *args) -> None:
        t = threading.Thread(target=target, args=args, name=name, daemon=True)
        t.start()
        self._threads.append(t)

    def _accept_loop(self) -> None:
        self._listener.settimeout(0.2)
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._clients.append(conn)
            self._spawn(self._serve, "socketcand-client", conn)

    def _serve(self, conn: socket.socket) -> None:
        bus: can.BusABC | None = None  # opened by "rawmode": the connection is in raw mode from then on
        buffer = b""
        try:
            conn.sendall(b"< hi >")
            conn.settimeout(0.2)
            opened = False
            while not self._stop.is_set():
                try:
                    data = conn.recv(65536)
                except TimeoutError:
                    continue
                if not data:
                    return
                buffer += data
                while True:
                    start = buffer.find(b"<")
                    end = buffer.find(b">", start + 1)
                    if start < 0 or end < 0:
                        break
                    words = parse_command(buffer[start : end + 1].decode("ascii", "replace"))
                    buffer = buffer[end + 1 :]
                    if not words:
                        continue
                    if bus is None:
                        if words[0] == "open":
                            if len(words) == 2 and words[1] == self.bus_name:
                                opened = True
                                conn.sendall(b"< ok >")
                            else:
                                conn.sendall(b"< error could not open bus >")
                        elif words[0] == "rawmode" and opened:
                            # frames flow only in raw mode and only after its "< ok >", as from socketcand
                            bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
                            conn.sendall(b"< ok >")
                            self._spawn(self._forward, "socketcand-forward", conn, bus)
                        else:
                            conn.sendall(b"< error unknown command >")
                    elif words[0] == "send" and len(words) >= 3:
                        can_id = int(words[1], 16)
                        dlc = int(words[2], 16)
                        payload = bytes(int(b, 16) for b in words[3 : 3 + dlc])
                        bus.send(can.Message(arbitration_id=can_id, is_extended_id=len(words[1]) > 3, data=payload))
        except (OSError, ValueError):
            return
        finally:
            try:
                conn.close()
            except OSError:
                pass
            if bus is not None:
                bus.shutdown()

    def _forward(self, conn: socket.socket, bus: can.BusABC) -> None:
        """Bus -> client: every frame, batched into one write when several are waiting."""
        try:
            while not self._stop.is_set():
                msg = bus.recv(timeout=0.2)
                if msg is None:
                    continue
                out = [format_frame(msg)]
                while len(out) < 256:
                    more = bus.recv(timeout=0)
                    if more is None:
                        break
                    out.append(format_frame(more))
                conn.sendall(b"".join(out))
        except (OSError, can.CanError):
            return

    def close(self) -> None:
        self._stop.set()
        try:
            self._listener.close()
        except OSError:
            pass
        with self._lock:
            for c in self._clients:
                try:
                    c.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
        for t in self._threads:
            t.join(timeout=1.0)
