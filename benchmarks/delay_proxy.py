"""A local TCP proxy that delays every chunk by a fixed time in each direction (a slow tunnel).

What an SSH tunnel to a far workstation adds: each byte arrives ``delay`` later, in order,
in both directions (round trip = 2 x delay), with no limit on bandwidth. It works on bytes,
so it carries the app's HTTP and its websocket alike.

Run: ``python benchmarks/delay_proxy.py --target 127.0.0.1:8080 --port 8090 --delay-ms 40``
(then open http://127.0.0.1:8090). :class:`DelayProxy` starts one from a benchmark, in a process of its own.
"""

from __future__ import annotations

import argparse
import asyncio
import subprocess
import sys
import time


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, delay: float) -> None:
    """Copy ``reader`` to ``writer``, each chunk written ``delay`` s after it was read (order kept)."""
    queue: asyncio.Queue = asyncio.Queue()

    async def read() -> None:
        try:
            while chunk := await reader.read(65536):
                queue.put_nowait((time.monotonic() + delay, chunk))
        except (ConnectionError, OSError):
            pass
        queue.put_nowait((time.monotonic() + delay, b""))

    async def write() -> None:
        while True:
            due, chunk = await queue.get()
            wait = due - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
            if not chunk:
                break
            writer.write(chunk)
            try:
                await writer.drain()
            except (ConnectionError, OSError):
                break
        try:
            writer.close()
        except Exception:
            pass

    await asyncio.gather(read(), write())


async def _serve(port: int, target: tuple[str, int], delay: float) -> asyncio.AbstractServer:
    async def handle(client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter) -> None:
        try:
            server_r, server_w = await asyncio.open_connection(*target)
        except OSError:
            client_w.close()
            return
        await asyncio.gather(_pipe(client_r, server_w, delay), _pipe(server_r, client_w, delay))

    return await asyncio.start_server(handle, "127.0.0.1", port)


class DelayProxy:
    """A running proxy in a process of its own, as an SSH tunnel is (``ssh`` and ``sshd`` are
    processes beside the app), so its copying never shares the app's interpreter (measured at
    40 ms each way: no difference to the thread it replaced). ``port`` to connect to,
    :meth:`stop` to end it."""

    def __init__(self, target: tuple[str, int], delay_ms: float, port: int = 0) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, __file__, "--target", f"{target[0]}:{target[1]}", "--port", str(port),
             "--delay-ms", str(delay_ms)], stdout=subprocess.PIPE, text=True)
        line = self._proc.stdout.readline()  # "127.0.0.1:PORT -> host:port, ..." once it listens
        if not line:
            raise RuntimeError("the delay proxy did not start")
        self.port = int(line.split()[0].rsplit(":", 1)[1])

    def stop(self) -> None:
        self._proc.terminate()
        try:
            self._proc.wait(5)
        except subprocess.TimeoutExpired:
            self._proc.kill()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--target", required=True, help="host:port of the app")
    parser.add_argument("--port", type=int, default=8090, help="port to listen on (127.0.0.1)")
    parser.add_argument("--delay-ms", type=float, default=40.0, help="delay each way")
    args = parser.parse_args()
    host, port = args.target.rsplit(":", 1)

    async def forever() -> None:
        server = await _serve(args.port, (host, int(port)), args.delay_ms / 1000.0)
        listening = server.sockets[0].getsockname()[1]
        print(f"127.0.0.1:{listening} -> {args.target}, {args.delay_ms:g} ms each way", flush=True)
        async with server:
            await server.serve_forever()

    try:
        asyncio.run(forever())
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
