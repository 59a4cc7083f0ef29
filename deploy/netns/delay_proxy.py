"""A TCP proxy that delays every byte by a latency with jitter, in both directions, keeping
order: the stand-in for `tc netem delay` where the kernel has no netem (multi-host-test.sh
--latency). Each chunk read is delivered at max(the previous chunk's delivery, now + d), d drawn
from a normal distribution (mean LATENCY, sd JITTER, at least 0), as netem delays packets
without reordering them.

    python3 delay_proxy.py LISTEN_HOST:PORT TARGET_HOST:PORT LATENCY_MS JITTER_MS

Prints `listening` once it is.
"""

import asyncio
import random
import sys
import time


async def pump(reader, writer, latency, jitter):
    queue = asyncio.Queue()

    async def deliver():
        while True:
            at, data = await queue.get()
            if data is None:
                break
            wait = at - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
            writer.write(data)
            await writer.drain()
        writer.close()

    sender = asyncio.create_task(deliver())
    last = 0.0
    try:
        while True:
            data = await reader.read(65536)
            if not data:
                break
            last = max(last, time.monotonic() + max(0.0, random.gauss(latency, jitter)))
            queue.put_nowait((last, data))
    except (ConnectionError, OSError):
        pass
    finally:
        queue.put_nowait((last, None))
        try:
            await sender
        except (ConnectionError, OSError):
            pass


async def main():
    (lh, lp), (th, tp) = (a.rsplit(":", 1) for a in sys.argv[1:3])
    latency, jitter = float(sys.argv[3]) / 1000.0, float(sys.argv[4]) / 1000.0

    async def handle(cr, cw):
        try:
            sr, sw = await asyncio.open_connection(th, int(tp))
        except OSError:
            cw.close()
            return
        await asyncio.gather(pump(cr, sw, latency, jitter), pump(sr, cw, latency, jitter))

    server = await asyncio.start_server(handle, lh, int(lp))
    print("listening", flush=True)
    async with server:
        await server.serve_forever()


if __name__ == "__main__":
    asyncio.run(main())
