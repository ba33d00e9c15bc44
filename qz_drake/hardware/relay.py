"""A relay server for LCM's ``tcpq://`` provider, bound to 127.0.0.1 (``qz lcm-relay``).

LCM's network provider ``udpm://`` sends every message to a multicast group. Two processes on
one machine (``qz robot-sim`` and a controller) need no group: with ``tcpq://127.0.0.1:PORT``
each process connects to this relay over TCP, and every packet stays on the loopback
interface. The protocol is LCM's own (``lcm/lcm_tcpq.c``, the client; ``lcm-java``'s
``TCPService``, the reference server), all integers big-endian uint32:

* handshake: the client sends MAGIC_CLIENT, VERSION; the server sends MAGIC_SERVER, VERSION;
* client -> server: SUBSCRIBE / UNSUBSCRIBE, channel length, channel (a regular expression);
  PUBLISH, channel length, channel, data length, data;
* server -> client: PUBLISH frames of every message whose channel a subscription of that
  client matches in full (the publisher's own included, as on ``udpm://``).

One thread serves all clients with ``selectors``: a relay is a copy from one socket to others
and never waits on one client. A client that does not read its messages gets no more once
``max_pending_bytes`` wait for it; those are counted as dropped (LCM's UDP providers also
drop what a slow receiver cannot take), and the other clients are not held up.
"""

from __future__ import annotations

import os
import re
import selectors
import socket
import stat
import struct
import time
from pathlib import Path

from qz_drake.errors import bad_value

MAGIC_SERVER = 0x287617FA
MAGIC_CLIENT = 0x287617FB
PROTOCOL_VERSION = 0x0100
PUBLISH, SUBSCRIBE, UNSUBSCRIBE = 1, 2, 3

# The only address the relay listens on: it exists for processes on this machine.
HOST = "127.0.0.1"
# LCM's tcpq default port.
DEFAULT_PORT = 7700
# A channel name longer than this is a broken client, not a channel (LCM allows 63 characters).
_MAX_CHANNEL = 1024
# A message larger than this is a broken client (qz_status is under 1 kB; LCM over UDP: 4 MB).
_MAX_DATA = 64 << 20
_UINT32 = struct.Struct(">I")


def tcpq_url(port: int) -> str:
    return f"tcpq://{HOST}:{port}"


class _Client:
    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.inbox = bytearray()
        self.outbox = bytearray()
        self.greeted = False
        self.subscriptions: list[tuple[str, re.Pattern]] = []

    def wants(self, channel: str) -> bool:
        return any(pattern.fullmatch(channel) for _, pattern in self.subscriptions)


class LcmTcpRelay:
    """LCM's tcpq server on 127.0.0.1: relays each published message to its subscribers.

    ``serve_forever()`` runs it until ``close()``. ``port=0`` takes a free port; ``port`` and
    ``url`` say which. (A relay in the same process as a DrakeLcm client would not do: LCM's
    tcpq client connects from inside DrakeLcm's constructor, which holds the interpreter.)

    Args:
        port: TCP port on 127.0.0.1.
        max_pending_bytes: bytes that may wait for one client before its messages are dropped.
    """

    def __init__(self, port: int = DEFAULT_PORT, *, max_pending_bytes: int = 4 << 20):
        if not 0 <= port <= 65535:
            raise bad_value("--port", port, "must be a TCP port, 0..65535 (0: any free one)")
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listener.bind((HOST, port))
        except OSError as e:
            self._listener.close()
            raise bad_value("--port", port, f"cannot listen on {HOST}:{port} ({e.strerror})") from None
        self._listener.listen()
        self._listener.setblocking(False)
        self.port = self._listener.getsockname()[1]
        self.url = tcpq_url(self.port)
        self._max_pending = max_pending_bytes
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ)
        # Written to by close() to wake the selector.
        self._wake_read, self._wake_write = socket.socketpair()
        self._selector.register(self._wake_read, selectors.EVENT_READ)
        self._clients: dict[socket.socket, _Client] = {}
        self._closing = False
        self.relayed = 0
        self.dropped = 0
        self.broken_clients = 0
        self.connections = 0

    def counters(self) -> dict:
        return {"url": self.url, "clients": len(self._clients), "connections": self.connections,
                "relayed": self.relayed, "dropped": self.dropped, "broken_clients": self.broken_clients}

    def close(self) -> None:
        """Makes serve_forever return (from a signal handler or another thread); it then closes
        every connection."""
        self._closing = True
        try:
            self._wake_write.send(b"x")
        except OSError:  # already closed
            pass

    def serve_forever(self) -> None:
        try:
            while not self._closing:
                for key, events in self._selector.select():
                    sock = key.fileobj
                    if sock is self._listener:
                        self._accept()
                    elif sock is self._wake_read:
                        self._wake_read.recv(64)
                    elif sock in self._clients:
                        client = self._clients[sock]
                        if events & selectors.EVENT_READ and not self._read(client):
                            continue
                        if events & selectors.EVENT_WRITE:
                            self._flush(client)
        finally:
            for client in list(self._clients.values()):
                self._drop_client(client)
            for sock in (self._listener, self._wake_read, self._wake_write):
                sock.close()
            self._selector.close()

    def _accept(self) -> None:
        try:
            sock, _ = self._listener.accept()
        except BlockingIOError:
            return
        sock.setblocking(False)
        # Each relayed message goes out in one send; Nagle's algorithm would hold the next
        # status back until the client acknowledged the previous one.
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client = _Client(sock)
        self._clients[sock] = client
        self.connections += 1
        self._selector.register(sock, selectors.EVENT_READ)
        self._queue(client, _UINT32.pack(MAGIC_SERVER) + _UINT32.pack(PROTOCOL_VERSION), force=True)

    def _read(self, client: _Client) -> bool:
        """Reads what ``client`` sent and handles every complete frame; False if it left."""
        try:
            data = client.sock.recv(1 << 16)
        except (BlockingIOError, InterruptedError):
            return True
        except OSError:
            data = b""
        if not data:
            self._drop_client(client)
            return False
        _acknowledge_at_once(client.sock)
        client.inbox += data
        try:
            self._handle_frames(client)
        except ValueError:
            self.broken_clients += 1
            self._drop_client(client)
            return False
        return True

    def _handle_frames(self, client: _Client) -> None:
        inbox = client.inbox
        at = 0
        if not client.greeted:
            if len(inbox) < 8:
                return
            if _UINT32.unpack_from(inbox, 0)[0] != MAGIC_CLIENT:
                raise ValueError("not an LCM tcpq client")
            client.greeted, at = True, 8
        while True:
            frame = _parse_frame(inbox, at)
            if frame is None:
                break
            kind, channel, end = frame
            if kind == PUBLISH:
                # The server's PUBLISH frame is the client's, byte for byte.
                self._relay(channel, bytes(inbox[at:end]))
            elif kind == SUBSCRIBE:
                try:
                    client.subscriptions.append((channel, re.compile(channel)))
                except re.error:
                    raise ValueError(f"bad subscription {channel!r}") from None
            else:
                client.subscriptions = [s for s in client.subscriptions if s[0] != channel]
            at = end
        del inbox[:at]

    def _relay(self, channel: str, frame: bytes) -> None:
        for client in list(self._clients.values()):
            if client.greeted and client.wants(channel):
                self._queue(client, frame)

    def _queue(self, client: _Client, data: bytes, *, force: bool = False) -> None:
        if not force and len(client.outbox) + len(data) > self._max_pending:
            self.dropped += 1
            return
        if not force:
            self.relayed += 1
        was_empty = not client.outbox
        client.outbox += data
        if was_empty:
            self._flush(client)

    def _flush(self, client: _Client) -> None:
        try:
            sent = client.sock.send(client.outbox)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError:
            self._drop_client(client)
            return
        del client.outbox[:sent]
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client.outbox else 0)
        self._selector.modify(client.sock, events)

    def _drop_client(self, client: _Client) -> None:
        if self._clients.pop(client.sock, None) is None:
            return
        self._selector.unregister(client.sock)
        client.sock.close()


def _acknowledge_at_once(sock: socket.socket) -> None:
    """Acknowledges what a client sent without the usual delay (Linux clears the option after
    each receive, hence on every one). LCM's tcpq client writes a message in five small sends
    without TCP_NODELAY: Nagle's algorithm holds the last four until the first is acknowledged,
    and a delayed acknowledgement (40 ms) held a 2 ms status stream back into bursts."""
    if hasattr(socket, "TCP_QUICKACK"):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_QUICKACK, 1)


def _parse_frame(buffer: bytearray, at: int):
    """(kind, channel, end) of the complete frame at ``at``, or None while it is incomplete."""
    if len(buffer) < at + 8:
        return None
    kind, length = _UINT32.unpack_from(buffer, at)[0], _UINT32.unpack_from(buffer, at + 4)[0]
    if kind not in (PUBLISH, SUBSCRIBE, UNSUBSCRIBE) or length > _MAX_CHANNEL:
        raise ValueError(f"bad frame (type {kind}, channel length {length})")
    end = at + 8 + length
    if len(buffer) < end:
        return None
    channel = bytes(buffer[at + 8:end]).decode("utf-8", errors="replace")
    if kind != PUBLISH:
        return kind, channel, end
    if len(buffer) < end + 4:
        return None
    size = _UINT32.unpack_from(buffer, end)[0]
    if size > _MAX_DATA:
        raise ValueError(f"message of {size} bytes")
    if len(buffer) < end + 4 + size:
        return None
    return kind, channel, end + 4 + size


# How long connect_lcm waits for a relay that is not listening yet (one started in the same
# breath, `qz lcm-relay ... &`, takes about 0.6 s to listen). [s]
RELAY_STARTUP = 5.0


# LCM's providers (lcm/lcm.c), what DrakeLcm accepts; with any other name it prints 'LCM
# provider "bogus" not found' and returns an instance that neither sends nor receives.
LCM_PROVIDERS = ("udpm", "mpudpm", "tcpq", "memq", "file")
# The options udpm takes (lcm/lcm_udpm.c); it ignores others with a printed warning.
_UDPM_OPTIONS = ("ttl", "recv_buf_size", "transmit_only")
# The modes of the file provider (lcm/lcm_file.c): read a log, write one, append to one.
_FILE_MODES = ("r", "w", "a")
_LCM_URL_EXAMPLE = "udpm://239.255.76.67:7667?ttl=1, tcpq://127.0.0.1:7700 or memq://"


def _url_port(url: str, field: str, port: str) -> None:
    if not (port.isdigit() and 1 <= int(port) <= 65535):
        raise bad_value(field, url, f"port {port!r} is not a port number, 1..65535")


def check_lcm_url(url, field: str = "lcm_url") -> str:
    """Refuses an LCM URL that DrakeLcm would take with only a printed error and then neither
    send nor receive on (an unknown provider, a multicast group that is no multicast address, a
    port out of range, a log file to read that does not exist). Errors name ``field`` and
    the URL; returns the URL."""
    import ipaddress

    if not isinstance(url, str) or not url.strip():
        raise bad_value(field, url, f"empty; expected an LCM URL, e.g. {_LCM_URL_EXAMPLE}")
    provider, sep, rest = url.partition("://")
    if not sep:
        raise bad_value(field, url, f"expected PROVIDER://..., e.g. {_LCM_URL_EXAMPLE}")
    if provider not in LCM_PROVIDERS:
        raise bad_value(field, url, f"unknown LCM provider {provider!r} (valid: "
                                    f"{', '.join(p + '://' for p in LCM_PROVIDERS)})")
    network, _, query = rest.partition("?")
    options = dict(item.partition("=")[::2] for item in query.split("&") if item)
    if provider in ("udpm", "mpudpm") and network:  # udpm:// alone is LCM's default group
        address, colon, port = network.rpartition(":")
        if not colon:
            raise bad_value(field, url, f"expected {provider}://GROUP:PORT, e.g. udpm://239.255.76.67:7667")
        try:
            multicast = ipaddress.IPv4Address(address).is_multicast
        except ValueError:
            multicast = False
        if not multicast:
            raise bad_value(field, url, f"{address!r} is not an IPv4 multicast group (224.0.0.0 to "
                                        f"239.255.255.255; LCM's default is 239.255.76.67)")
        _url_port(url, field, port)
    if provider == "udpm":
        for key, value in options.items():
            if key not in _UDPM_OPTIONS:
                raise bad_value(field, url, f"unknown udpm option {key!r} (valid: {', '.join(_UDPM_OPTIONS)})")
        if "ttl" in options and not (options["ttl"].isdigit() and int(options["ttl"]) <= 255):
            raise bad_value(field, url, f"ttl {options['ttl']!r} is not a hop count, 0..255")
    if provider == "tcpq" and ":" in network:
        _url_port(url, field, network.rpartition(":")[2])
    if provider == "file":
        mode = options.get("mode", "r")
        if not network:
            raise bad_value(field, url, "names no log file, e.g. file:///tmp/run.lcm?mode=w")
        if mode not in _FILE_MODES:
            raise bad_value(field, url, f"mode {mode!r} is not one of {', '.join(_FILE_MODES)}")
        if mode == "r" and not Path(network).is_file():
            raise bad_value(field, url, f"no log file {network} to read (mode=w writes one)")
    return url


def connect_lcm(url: str, field: str = "lcm_url"):
    """DrakeLcm(url); for a ``tcpq://`` URL only once a relay accepts connections there.

    LCM's tcpq client that finds no server prints "Unable to connect" and returns an instance
    that neither sends nor receives: a controller would then wait for a robot that never
    answers. Errors name ``field`` and the URL.
    """
    from pydrake.lcm import DrakeLcm

    check_lcm_url(url, field)
    if url.startswith("tcpq://"):
        host, _, port = url[len("tcpq://"):].split("?")[0].partition(":")
        try:
            port_number = int(port) if port else DEFAULT_PORT
        except ValueError:
            raise bad_value(field, url, "expected tcpq://HOST:PORT") from None
        deadline = time.monotonic() + RELAY_STARTUP
        while True:
            try:
                socket.create_connection((host or HOST, port_number), timeout=2.0).close()
                break
            except OSError as e:
                if time.monotonic() > deadline:
                    raise bad_value(field, url, f"no LCM relay answers there ({e.strerror or e}); start one "
                                                f"with `qz lcm-relay --port {port_number}`") from None
                time.sleep(0.1)
    try:
        lcm = DrakeLcm(url)
    except RuntimeError as e:
        raise bad_value(field, url, str(e)) from None
    if url.startswith("tcpq://"):
        send_at_once(host or HOST, port_number)
    return lcm


def send_at_once(host: str, port: int) -> int:
    """Sets TCP_NODELAY on this process's connections to ``host:port`` (LCM's tcpq clients
    connected to a relay); returns how many it found.

    LCM's tcpq client writes a message in five sends (type, channel length, channel, data
    length, data) on a socket left with Nagle's algorithm: the last four wait until the relay
    acknowledges the first, and a relay that also sends to that client (commands to the
    driver, statuses to the servo) is answered with delayed acknowledgements, up to 40 ms. The
    relay's own quick acknowledgements (_acknowledge_at_once) shortened most of those waits but
    not all: two-process walks still ended in safe stops for statuses that were sent on time and
    arrived 22-30 ms later. The client's socket is not LCM's to give, so it is found among this
    process's file descriptors by its peer."""
    found, peer = 0, (socket.gethostbyname(host), port)
    try:
        fds = [int(name) for name in os.listdir("/proc/self/fd")]
    except OSError:  # not Linux: nothing to find
        return 0
    for fd in fds:
        try:
            if not stat.S_ISSOCK(os.fstat(fd).st_mode):
                continue
            sock = socket.socket(fileno=os.dup(fd))
        except OSError:
            continue
        try:
            if sock.type == socket.SOCK_STREAM and sock.family == socket.AF_INET and \
                    sock.getpeername() == peer:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                found += 1
        except OSError:  # not connected
            pass
        finally:
            sock.close()
    return found
