"""The foxglove node's relay, against a stand-in server on a socket: the older subprotocol
name is renamed both ways in the handshake and nothing else changes; a handshake head
beyond the bound is dropped before any server is contacted."""

from contextlib import contextmanager
import socket
import threading

from hydropump_ros.subprotocols import MAX_HEAD, Relay

REQUEST = (b'GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n'
           b'Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n'
           b'Sec-WebSocket-Protocol: %s\r\n\r\n')
ANSWER = (b'HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n'
          b'Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n'
          b'sec-websocket-protocol: foxglove.sdk.v1\r\n\r\n')


class Server:
    """Answers one handshake with ANSWER, then echoes; keeps what it received."""

    def __init__(self):
        self.sock = socket.create_server(('127.0.0.1', 0))
        self.port = self.sock.getsockname()[1]
        self.got = b''
        self.accepted = threading.Event()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self):
        conn, _ = self.sock.accept()
        self.accepted.set()
        with conn:
            while b'\r\n\r\n' not in self.got:
                self.got += conn.recv(4096)
            conn.sendall(ANSWER)
            while data := conn.recv(4096):
                conn.sendall(data)


def _recv_until(sock, marker: bytes) -> bytes:
    out = b''
    while marker not in out:
        chunk = sock.recv(4096)
        assert chunk, out
        out += chunk
    return out


@contextmanager
def relayed():
    """A stand-in server, the relay in front of it, and a client connected to the relay."""
    server = Server()
    relay = Relay('127.0.0.1', 0, server.port)
    try:
        with socket.create_connection(('127.0.0.1', relay.port), timeout=10) as c:
            yield server, c
    finally:
        relay.stop()


def test_the_old_name_is_renamed_both_ways_and_the_rest_passes_untouched():
    with relayed() as (server, c):
        c.sendall(REQUEST % b'foxglove.websocket.v1')
        answer = _recv_until(c, b'\r\n\r\n')
        assert answer == ANSWER.replace(b'foxglove.sdk.v1', b'foxglove.websocket.v1')
        assert server.got == REQUEST % b'foxglove.sdk.v1'
        frame = bytes(range(256)) * 8 + b'Sec-WebSocket-Protocol: foxglove.sdk.v1'
        c.sendall(frame)
        assert _recv_until(c, b'sdk.v1') == frame  # echoed as sent, both ways


def test_a_client_offering_the_new_name_passes_unchanged():
    with relayed() as (server, c):
        request = REQUEST % b'foxglove.websocket.v1, foxglove.sdk.v1'
        c.sendall(request)
        assert _recv_until(c, b'\r\n\r\n') == ANSWER
        assert server.got == request


def test_a_head_beyond_the_bound_is_dropped_before_the_server_is_contacted():
    with relayed() as (server, c):
        try:
            c.sendall(b'GET / HTTP/1.1\r\nX: ' + b'a' * (2 * MAX_HEAD))
        except (BrokenPipeError, ConnectionResetError):
            pass
        try:
            closed = c.recv(1) == b''
        except ConnectionResetError:
            closed = True
        assert closed and not server.accepted.is_set()
