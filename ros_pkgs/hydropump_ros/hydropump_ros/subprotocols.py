"""Both names of the Foxglove WebSocket protocol on one port.

The Foxglove SDK's server accepts the subprotocol ``foxglove.sdk.v1`` only, and answers a
client that offers only the older name ``foxglove.websocket.v1`` (Lichtblick, older Foxglove
Studio, ``foxglove_bridge`` 0.8 clients) with HTTP 400. The two are the same protocol under
two names (Foxglove's own statement; Lichtblick and Flora added the new name beside the old
one). So the node's port is served by this relay: it reads the client's opening handshake
(an HTTP request head, at most :data:`MAX_HEAD` bytes), renames the old subprotocol to the
new one for the SDK's server behind it, renames it back in the server's answer, and from
then on passes the bytes through untouched. ``Sec-WebSocket-Accept`` depends on the key
alone, so the renamed handshake stays valid. A client that offers the new name passes
unchanged.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading

OLD = 'foxglove.websocket.v1'
NEW = 'foxglove.sdk.v1'
# Bytes of a handshake head read before the relay gives up on it (browsers send about 1 KiB).
MAX_HEAD = 64 * 1024
HEADER = b'sec-websocket-protocol'


def rename(head: bytes, old: str, new: str) -> bytes:
    """``head`` (an HTTP head, CRLF lines) with ``old`` replaced by ``new`` among the values
    of its ``Sec-WebSocket-Protocol`` headers; every other byte as it was."""
    lines = head.split(b'\r\n')
    for k, line in enumerate(lines):
        name, sep, value = line.partition(b':')
        if sep and name.strip().lower() == HEADER:
            names = [v.strip() for v in value.decode('latin-1').split(',')]
            value = ', '.join(new if v == old else v for v in names)
            lines[k] = name + b': ' + value.encode('latin-1')
    return b'\r\n'.join(lines)


def offered(head: bytes) -> list[str]:
    """The subprotocols a handshake head offers, in its order."""
    out = []
    for line in head.split(b'\r\n')[1:]:
        name, sep, value = line.partition(b':')
        if sep and name.strip().lower() == HEADER:
            out += [v.strip() for v in value.decode('latin-1').split(',') if v.strip()]
    return out


async def _head(reader: asyncio.StreamReader) -> bytes | None:
    try:
        return await reader.readuntil(b'\r\n\r\n')
    except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError):
        return None


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, asyncio.CancelledError):
        pass
    finally:
        with contextlib.suppress(Exception):
            writer.close()


class Relay:
    """Serves ``host:port`` in a thread of its own and relays each connection to the
    server on ``127.0.0.1:backend`` (see the module). :class:`OSError` if the address
    cannot be bound."""

    def __init__(self, host: str, port: int, backend: int):
        self.backend = backend
        self._loop = asyncio.new_event_loop()
        # Bound here, in the caller's thread, so that a port in use is the caller's error.
        self._sock = socket.create_server((host, port), reuse_port=False)
        self._sock.setblocking(False)
        self.port = self._sock.getsockname()[1]
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name='ws-relay', daemon=True)
        self._thread.start()
        self._ready.wait()

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)

        async def start():
            self._server = await asyncio.start_server(self._serve, sock=self._sock,
                                                      limit=MAX_HEAD)
            self._ready.set()
        self._loop.run_until_complete(start())
        self._loop.run_forever()
        # Stopped: close the listener and every relayed connection.
        self._server.close()
        tasks = asyncio.all_tasks(self._loop)
        for t in tasks:
            t.cancel()
        self._loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
        self._loop.close()

    async def _serve(self, client_r: asyncio.StreamReader,
                     client_w: asyncio.StreamWriter) -> None:
        server_w = None
        try:
            head = await _head(client_r)
            if head is None:
                return
            renamed = OLD in offered(head) and NEW not in offered(head)
            try:
                server_r, server_w = await asyncio.open_connection(
                    '127.0.0.1', self.backend, limit=MAX_HEAD)
            except OSError:
                return
            server_w.write(rename(head, OLD, NEW) if renamed else head)
            await server_w.drain()
            answer = await _head(server_r)
            if answer is None:
                return
            client_w.write(rename(answer, NEW, OLD) if renamed else answer)
            await client_w.drain()
            await asyncio.gather(_pipe(client_r, server_w), _pipe(server_r, client_w))
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            for w in (client_w, server_w):
                if w is not None:
                    with contextlib.suppress(Exception):
                        w.close()

    def stop(self) -> None:
        """Close the port and every relayed connection; returns once the thread ends."""
        if self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5.0)
