"""One port for both Foxglove WebSocket subprotocols: ``foxglove.sdk.v1`` and the classic ``foxglove.websocket.v1``.

Foxglove's own server (the ``foxglove-sdk`` package) accepts only ``foxglove.sdk.v1`` and answers a
client that offers only the classic ``foxglove.websocket.v1`` with HTTP 400. Lichtblick, older
Foxglove apps and Foxglove's ``ws-protocol`` clients offer only the classic name. The two are the
same protocol under two names (Foxglove's stated position for ``sdk.v1``; our tests run a classic
client end to end to hold it), so :class:`SubprotocolFront` listens on the user's port and hands
every connection to the SDK server on a loopback port:

* the client's upgrade request is read (at most :data:`MAX_HEADER_BYTES`, within ``header_timeout_s``);
  if it offers ``foxglove.websocket.v1`` but not ``foxglove.sdk.v1``, the offer is renamed to
  ``foxglove.sdk.v1`` before it goes on, and the server's answer is renamed back, so the client sees
  the name it asked for (``Sec-WebSocket-Accept`` depends only on the key, so it stays valid);
* from then on the bytes pass unchanged both ways (one thread per direction); the server's first frames
  go on 50 ms after its answer, not in the same read (a client that attaches its handlers on the open
  event, as Foxglove's ``mcap-record`` does, would lose them).

A request that offers ``foxglove.sdk.v1`` (or anything else) passes unchanged, so the SDK server
keeps deciding what it accepts. A request that never ends its header, or one too long, gets
``400 Bad Request`` from the front and is closed.
"""

from __future__ import annotations

import socket
import threading
import time

__all__ = ["CLASSIC", "MAX_HEADER_BYTES", "SDK", "SubprotocolFront"]

CLASSIC = "foxglove.websocket.v1"
SDK = "foxglove.sdk.v1"
MAX_HEADER_BYTES = 16 * 1024
_HEADER_END = b"\r\n\r\n"
_PROTOCOL_HEADER = b"sec-websocket-protocol"
_AFTER_HANDSHAKE_S = 0.05
_BAD_REQUEST = b"HTTP/1.1 400 Bad Request\r\nConnection: close\r\nContent-Length: 0\r\n\r\n"


def _read_head(sock: socket.socket) -> tuple[bytes, bytes] | None:
    """(header up to and including the blank line, bytes after it); None if the peer closed, timed out
    or sent more than :data:`MAX_HEADER_BYTES` without ending the header."""
    buf = b""
    while _HEADER_END not in buf:
        if len(buf) > MAX_HEADER_BYTES:
            return None
        try:
            chunk = sock.recv(4096)
        except OSError:  # timeout or reset
            return None
        if not chunk:
            return None
        buf += chunk
    end = buf.index(_HEADER_END) + len(_HEADER_END)
    return buf[:end], buf[end:]


def offered(head: bytes) -> list[str]:
    """The subprotocols an HTTP upgrade request offers, in order (every ``Sec-WebSocket-Protocol`` line)."""
    out = []
    for line in head.split(b"\r\n")[1:]:
        name, sep, value = line.partition(b":")
        if sep and name.strip().lower() == _PROTOCOL_HEADER:
            out += [t.strip() for t in value.decode("latin-1").split(",") if t.strip()]
    return out


def rename_protocol(head: bytes, old: str, new: str) -> bytes:
    """``head`` with the token ``old`` replaced by ``new`` in its ``Sec-WebSocket-Protocol`` lines."""
    lines = head.split(b"\r\n")
    for i, line in enumerate(lines[1:], start=1):
        name, sep, value = line.partition(b":")
        if sep and name.strip().lower() == _PROTOCOL_HEADER:
            tokens = [t.strip() for t in value.decode("latin-1").split(",")]
            lines[i] = name + b": " + ", ".join(new if t == old else t for t in tokens).encode("latin-1")
    return b"\r\n".join(lines)


class SubprotocolFront:
    """Listens on ``host:port`` (0: a free port, see :attr:`port`) and serves each connection through
    the WebSocket server on ``127.0.0.1:upstream_port`` (module docstring).

    header_timeout_s : how long a client may take to send its upgrade request.
    Raises ``OSError`` when ``host:port`` cannot be bound.
    """

    def __init__(self, host: str, port: int, upstream_port: int, *, header_timeout_s: float = 5.0):
        self.upstream = ("127.0.0.1", int(upstream_port))
        self.header_timeout_s = float(header_timeout_s)
        self._listener = socket.create_server((host, port), reuse_port=False)
        self._listener.settimeout(0.2)
        self.port = self._listener.getsockname()[1]
        self.connections = {"classic": 0, "passed": 0, "refused": 0}
        self._open: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept_loop, name="rt2-ws-front", daemon=True)
        self._thread.start()

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            threading.Thread(target=self._serve, args=(conn,), name="rt2-ws-conn", daemon=True).start()

    def _track(self, *socks: socket.socket) -> bool:
        with self._lock:
            if self._stop.is_set():
                return False
            self._open.update(socks)
            return True

    def _serve(self, client: socket.socket) -> None:
        upstream = None
        try:
            if not self._track(client):
                return
            client.settimeout(self.header_timeout_s)
            got = _read_head(client)
            if got is None:
                self.connections["refused"] += 1
                client.sendall(_BAD_REQUEST)
                return
            head, rest = got
            protocols = offered(head)
            classic = CLASSIC in protocols and SDK not in protocols
            if classic:
                head = rename_protocol(head, CLASSIC, SDK)
            upstream = socket.create_connection(self.upstream, timeout=self.header_timeout_s)
            if not self._track(upstream):
                return
            upstream.sendall(head + rest)
            answer = _read_head(upstream)
            if answer is None:
                client.sendall(_BAD_REQUEST)
                return
            reply, rest = answer
            if classic:
                reply = rename_protocol(reply, SDK, CLASSIC)
            client.sendall(reply)
            # The server's first frames (serverInfo, advertise) follow its answer by microseconds; a client that
            # reads both in one chunk and attaches its handlers on the open event (Foxglove's mcap-record does)
            # loses them. They go on no sooner than _AFTER_HANDSHAKE_S after the answer.
            not_before = time.monotonic() + _AFTER_HANDSHAKE_S
            self.connections["classic" if classic else "passed"] += 1
            client.settimeout(None)
            upstream.settimeout(None)
            back = threading.Thread(target=_pump, args=(upstream, client, rest, not_before), name="rt2-ws-pump", daemon=True)
            back.start()
            _pump(client, upstream)
            back.join()
        except OSError:
            pass  # a client or the server went away: that connection ends, the front goes on
        finally:
            for s in (client, upstream):
                if s is not None:
                    with self._lock:
                        self._open.discard(s)
                    s.close()

    def close(self) -> None:
        """Stop listening and end every open connection."""
        with self._lock:
            self._stop.set()
            socks = list(self._open)
        self._listener.close()
        for s in socks:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self._thread.join(timeout=2.0)


def _pump(src: socket.socket, dst: socket.socket, first: bytes = b"", not_before: float = 0.0) -> None:
    """Copy ``first``, then ``src``, to ``dst`` until ``src`` ends (nothing before ``time.monotonic()`` reaches
    ``not_before``); then end ``dst``'s sending side."""
    try:
        data = first or src.recv(65536)
        time.sleep(max(0.0, not_before - time.monotonic()))
        while data:
            dst.sendall(data)
            data = src.recv(65536)
    except OSError:
        pass
    finally:
        try:
            dst.shutdown(socket.SHUT_WR)
        except OSError:
            pass
