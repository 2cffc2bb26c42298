"""Why the daemon's relays receive into a buffer of their own: `sock.recv(1 MiB)` per message
against `sock.recv_into(buffer)`, with nothing of imud or Zenoh, and the process's RSS.

A child process sends `--rate` messages a second of `--size` bytes, in turn over `--receivers`
SOCK_SEQPACKET socket pairs (as bus processes send batches); this process receives them on a
thread per socket with a 0.5 s timeout (as the relays in `imud.buslink` do), copies each one's
payload out and keeps the last `--keep` payloads alive (Zenoh's queues hold a batch for a while
after `put`), while another thread allocates small objects living a few ms to a minute
(everything else the daemon does). Every `--interval` seconds it prints the RSS and glibc's
heaps (`[heap]` plus its other arenas, from bench/memwatch.py), and at the end what
`malloc_trim(0)` gives back. The first receives time out before the child sends anything, and
CPython frees those 1 MiB buffers whole: glibc then raises its mmap threshold past 1 MiB, so
every later `recv(1 MiB)` is cut out of a heap instead of being mmapped.

Measured (2 vCPUs, defaults, 90 s): heaps 13.7 MB at 10 s and 15.1 MB at 90 s with `recv`,
5.2 and 6.6 MB with `recv_into` (RSS 27.8 against 19.4 MB at the end). The daemon itself, where
Zenoh's threads allocate in the same heaps, kept growing (docs/reliability.md, "Soak").

    .venv/bin/python bench/recv_heap.py --mode recv
    .venv/bin/python bench/recv_heap.py --mode recv_into
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import ctypes
import itertools
import mmap
import os
import random
import socket
import threading
import time

from memwatch import breakdown

RECV_MAX = 1 << 20


def sender(socks: list[socket.socket], rate: float, size: int, seconds: float) -> None:
    """`rate` messages a second in all, to each socket in turn."""
    time.sleep(0.7)  # the receivers' first recv times out, as a relay's does while a child starts
    msg = os.urandom(size)
    period = 1.0 / rate
    t = time.monotonic()
    end = t + seconds
    for sock in itertools.cycle(socks):
        if t >= end:
            break
        with contextlib.suppress(BlockingIOError):
            sock.send(msg, socket.MSG_DONTWAIT)
        t += period
        time.sleep(max(0.0, t - time.monotonic()))
    for sock in socks:
        sock.close()


def churn(stop: threading.Event) -> None:
    """Small allocations living a few ms to a minute (1000-2000 alive at a time)."""
    rng = random.Random(1)
    live: list[tuple[float, bytes]] = []
    while not stop.is_set():
        now = time.monotonic()
        for _ in range(2):
            life = rng.expovariate(1.0 if rng.random() < 0.9 else 0.05)
            live.append((now + life, b"x" * rng.randrange(520, 2000)))
        live = [x for x in live if x[0] > now]
        time.sleep(0.002)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--mode", choices=("recv", "recv_into"), default="recv")
    ap.add_argument("--rate", type=float, default=5000.0, help="messages a second")
    ap.add_argument("--size", type=int, default=600, help="bytes a message")
    ap.add_argument("--receivers", type=int, default=4, help="sockets, a thread each (relays)")
    ap.add_argument("--keep", type=int, default=2000, help="payloads kept alive (a queue)")
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--interval", type=float, default=10.0)
    args = ap.parse_args()

    pairs = [
        socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET) for _ in range(args.receivers)
    ]
    pid = os.fork()
    if pid == 0:
        for ours, _ in pairs:
            ours.close()
        sender([theirs for _, theirs in pairs], args.rate, args.size, args.seconds)
        os._exit(0)
    for _, theirs in pairs:
        theirs.close()
    stop = threading.Event()
    threading.Thread(target=churn, args=(stop,), daemon=True).start()
    kept: collections.deque[bytes] = collections.deque(maxlen=args.keep)
    received = [0]

    def receive(ours: socket.socket) -> None:
        buf = mmap.mmap(-1, RECV_MAX, flags=mmap.MAP_PRIVATE)
        view = memoryview(buf)
        ours.settimeout(0.5)
        while True:
            try:
                if args.mode == "recv":
                    msg = ours.recv(RECV_MAX)
                    if not msg:
                        return
                    payload = msg[3:]
                else:
                    n = ours.recv_into(buf)
                    if not n:
                        return
                    payload = view[3:n].tobytes()
            except TimeoutError:
                continue
            kept.append(payload)
            received[0] += 1

    rxs = [threading.Thread(target=receive, args=(ours,)) for ours, _ in pairs]
    for rx in rxs:
        rx.start()
    t0 = time.monotonic()
    print(f"mode {args.mode}: {args.rate:g} messages/s of {args.size} B for {args.seconds:g} s")
    print("     t  received    rss   heap+arenas (MB)")
    while any(rx.is_alive() for rx in rxs):
        b = breakdown(os.getpid())
        print(f"{time.monotonic() - t0:6.0f} {received[0]:9d} {b['rss']:6.1f} "
              f"{b['heap'] + b['arenas']:6.1f}", flush=True)  # fmt: skip
        time.sleep(args.interval)
    stop.set()
    os.waitpid(pid, 0)
    before = breakdown(os.getpid())
    ctypes.CDLL(None).malloc_trim(0)
    after = breakdown(os.getpid())
    print(f"end: RSS {before['rss']:.1f} MB, heap+arenas {before['heap'] + before['arenas']:.1f} "
          f"MB; after malloc_trim(0) {after['rss']:.1f} MB, heap+arenas "
          f"{after['heap'] + after['arenas']:.1f} MB")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
