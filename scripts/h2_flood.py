#!/usr/bin/env python3
"""An idle HTTP/2 flood against a running `vamos serve`, and what it does to health checks.

Opens CONNECTIONS connections to the gRPC port from ADDRESSES loopback source addresses
(127.0.3.1, 127.0.3.2, ...). Each sends the HTTP/2 preface and SETTINGS, acknowledges the
server's SETTINGS, answers every PING and sends nothing else; when the server closes one,
it reconnects at once (an attacker that keeps trying). Meanwhile a health check from
127.0.0.1 (`GET /healthz` on the REST port, a new connection each time, 1 s timeout) runs
every 0.2 s. Prints one JSON object: the health checks' answers and latency percentiles,
and the attackers' connections served, refused (closed before the server's SETTINGS) and
closed by the server after being served.

    python3 scripts/h2_flood.py --grpc 127.0.0.1:8081 --rest 127.0.0.1:8080 \
        --connections 5000 --addresses 8 --duration 120

Only the standard library; Linux (any 127.x.y.z address is loopback). Figures of the runs
made: benches/README.md#reliability.
"""

import argparse
import asyncio
import json
import statistics
import time

PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
SETTINGS_ACK = bytes([0, 0, 0, 4, 1, 0, 0, 0, 0])


class Tally:
    def __init__(self):
        self.served = 0
        self.refused = 0
        self.closed_by_server = 0
        self.pings = 0
        self.open_now = 0
        self.peak_open = 0


async def idle_peer(host, port, src, tally, stop):
    """One attacker slot: connect, idle, reconnect when closed, until `stop`."""
    while not stop.is_set():
        try:
            reader, writer = await asyncio.open_connection(host, port, local_addr=(src, 0))
        except OSError:
            await asyncio.sleep(0.1)
            continue
        served = False
        try:
            writer.write(PREFACE)
            await writer.drain()
            while not stop.is_set():
                head = await reader.readexactly(9)
                length = int.from_bytes(head[0:3], "big")
                kind, flags = head[3], head[4]
                payload = await reader.readexactly(length) if length else b""
                if kind == 4 and not flags & 1:
                    if not served:
                        served = True
                        tally.served += 1
                        tally.open_now += 1
                        tally.peak_open = max(tally.peak_open, tally.open_now)
                    writer.write(SETTINGS_ACK)
                elif kind == 6 and not flags & 1:
                    tally.pings += 1
                    writer.write(bytes([0, 0, 8, 6, 1, 0, 0, 0, 0]) + payload)
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError, OSError):
            pass
        finally:
            if served:
                tally.open_now -= 1
                if not stop.is_set():
                    tally.closed_by_server += 1
            else:
                tally.refused += 1
            writer.close()
        await asyncio.sleep(0.05)


async def health_check(host, port):
    """`GET /healthz` on a new connection: (status, seconds), or (None, seconds)."""
    t0 = time.monotonic()
    try:
        reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), 1.0)
        writer.write(f"GET /healthz HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode())
        await writer.drain()
        line = await asyncio.wait_for(reader.readline(), 1.0)
        writer.close()
        status = int(line.split()[1]) if line.startswith(b"HTTP/") else None
    except (asyncio.TimeoutError, OSError, ValueError, IndexError):
        status = None
    return status, time.monotonic() - t0


async def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--grpc", default="127.0.0.1:8081")
    p.add_argument("--rest", default="127.0.0.1:8080")
    p.add_argument("--connections", type=int, default=5000)
    p.add_argument("--addresses", type=int, default=8)
    p.add_argument("--duration", type=float, default=120.0)
    a = p.parse_args()
    ghost, gport = a.grpc.rsplit(":", 1)
    rhost, rport = a.rest.rsplit(":", 1)
    tally = Tally()
    stop = asyncio.Event()
    peers = [
        asyncio.create_task(
            idle_peer(ghost, int(gport), f"127.0.3.{1 + i % a.addresses}", tally, stop)
        )
        for i in range(a.connections)
    ]
    checks = []
    t_end = time.monotonic() + a.duration
    while time.monotonic() < t_end:
        checks.append(await health_check(rhost, int(rport)))
        await asyncio.sleep(0.2)
    stop.set()
    for t in peers:
        t.cancel()
    await asyncio.gather(*peers, return_exceptions=True)
    ok = [s for st, s in checks if st == 200]
    q = statistics.quantiles(ok, n=100) if len(ok) >= 2 else [float("nan")] * 99
    print(json.dumps({
        "connections": a.connections,
        "addresses": a.addresses,
        "duration_s": a.duration,
        "health_checks": len(checks),
        "health_ok": len(ok),
        "health_p50_ms": round(q[49] * 1e3, 1),
        "health_p99_ms": round(q[98] * 1e3, 1),
        "health_max_ms": round(max(ok) * 1e3, 1) if ok else None,
        "attacker_served": tally.served,
        "attacker_refused": tally.refused,
        "attacker_closed_by_server": tally.closed_by_server,
        "attacker_peak_open": tally.peak_open,
        "pings_answered": tally.pings,
    }, indent=2))


if __name__ == "__main__":
    asyncio.run(main())
