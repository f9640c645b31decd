"""A lossy, slow, reordering wire between two network interfaces, in user space: what ``tc qdisc … netem`` does,
for kernels built without netem (this one has only tbf and htb).

    python -m tests.wire IF_A IF_B --loss 0.05 --delay 0.02 --jitter 0.005   # forward frames both ways
    python -m tests.wire --software IF ...                                   # no offloads on IF (see below)

It forwards each Ethernet frame read on one interface to the other at once until SIGUSR1; from then on, it
drops each with probability ``loss``, or writes it after ``delay`` ± ``jitter`` seconds (uniform), each frame
on its own: frames sent close together overtake each other. Prints "ready" once both interfaces are open
and, at SIGTERM, what it did since SIGUSR1: "forwarded N dropped N
reordered N" (frames sent before one read earlier in the same direction). The two interfaces are the
wire's ends (veths in a namespace of their own); the interfaces that send into them must checksum and
segment in software (``--software``), or frames read off the wire would carry checksums left to a NIC and
be too long.
"""

from __future__ import annotations

import argparse
import ctypes
import fcntl
import heapq
import random
import signal
import socket
import struct
import sys
import threading
import time

ETH_P_ALL = 3
PACKET_OUTGOING = 4  # a frame this side sent: ours, not one to forward
SIOCETHTOOL = 0x8946
# legacy ethtool commands that switch off one offload: tx checksums, scatter-gather, TCP and generic segmentation
OFFLOADS_OFF = (0x17, 0x19, 0x1F, 0x24)


def software(interface: str) -> None:
    """Switch off ``interface``'s offloads: every frame leaves it checksummed and no longer than its MTU."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for cmd in OFFLOADS_OFF:
            value = ctypes.create_string_buffer(struct.pack("II", cmd, 0))  # struct ethtool_value, read by pointer
            fcntl.ioctl(sock, SIOCETHTOOL, struct.pack("16sP16x", interface.encode(), ctypes.addressof(value)))


class Wire:
    def __init__(self, ends: tuple[str, str], loss: float, delay: float, jitter: float, seed: int) -> None:
        self.socks = []
        for end in ends:
            sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
            sock.bind((end, 0))
            self.socks.append(sock)
        self.loss, self.delay, self.jitter = loss, delay, jitter
        self.faulty = False  # from SIGUSR1
        self.rng = random.Random(seed)
        self.due: list[tuple[float, int, int, bytes]] = []  # (when, order, to which end, frame)
        self.order = 0
        self.changed = threading.Condition()
        self.last = [0.0, 0.0]  # to each end: when the latest frame read is due
        self.counts = {"forwarded": 0, "dropped": 0, "reordered": 0}

    def read(self, end: int) -> None:
        sock = self.socks[end]
        while True:
            frame, address = sock.recvfrom(65536)
            if address[2] == PACKET_OUTGOING:
                continue
            with self.changed:
                if not self.faulty:
                    when = time.monotonic()
                elif self.rng.random() < self.loss:
                    self.counts["dropped"] += 1
                    continue
                else:
                    when = time.monotonic() + self.delay + self.rng.uniform(-self.jitter, self.jitter)
                self.counts["reordered"] += when < self.last[1 - end]
                self.last[1 - end] = max(when, self.last[1 - end])
                self.order += 1
                heapq.heappush(self.due, (when, self.order, 1 - end, frame))
                self.changed.notify()

    def write(self) -> None:
        while True:
            with self.changed:
                while not self.due or (left := self.due[0][0] - time.monotonic()) > 0:
                    self.changed.wait(None if not self.due else left)
                _, _, end, frame = heapq.heappop(self.due)
                self.counts["forwarded"] += self.faulty
            self.socks[end].send(frame)

    def run(self) -> None:
        def report(signum: int, frame: object) -> None:
            print(" ".join(f"{k} {v}" for k, v in self.counts.items()), flush=True)
            sys.exit(0)

        def strike(signum: int, frame: object) -> None:
            self.faulty = True

        signal.signal(signal.SIGTERM, report)
        signal.signal(signal.SIGUSR1, strike)
        for end in (0, 1):
            threading.Thread(target=self.read, args=(end,), daemon=True).start()
        print("ready", flush=True)
        self.write()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m tests.wire", description=__doc__.split("\n\n")[0])
    parser.add_argument("interfaces", nargs="+")
    parser.add_argument("--software", action="store_true", help="only switch off the interfaces' offloads")
    parser.add_argument("--loss", type=float, default=0.0, help="probability that a frame is dropped")
    parser.add_argument("--delay", type=float, default=0.0, help="seconds each frame waits, on average")
    parser.add_argument("--jitter", type=float, default=0.0, help="± seconds around --delay, uniform")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.software:
        for interface in args.interfaces:
            software(interface)
        return
    if len(args.interfaces) != 2:
        parser.error("a wire has two ends")
    Wire((args.interfaces[0], args.interfaces[1]), args.loss, args.delay, args.jitter, args.seed).run()


if __name__ == "__main__":
    main()
