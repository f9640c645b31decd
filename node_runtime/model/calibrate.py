"""Calibrating payloads: how fast a machine does a fixed reference kernel, per CPU-second of one thread.

Run it on the machine that runs the emulation (the host) and on a device a profile stands for; a
payload that took s CPU-seconds on the host then takes s x host_rate / device_rate seconds on the
device, which a profile states as ``payload_hz = cores x frequency x host_rate / device_rate``
(docs/model.md, "Payloads: real work in the loop"; docs/extending.md, "Real work in the loop").

    python -m node_runtime.model.calibrate                                   # this machine's rate
    python -m node_runtime.model.calibrate --host-rate R --cores 1 --frequency 1e8   # and its payload_hz
    python -m node_runtime.model.calibrate --call mylab:infer --args '{"batch": 16}'  # a payload's own rate
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable

import numpy as np

from node_runtime.model.plugins import PluginError, extend_path, load

KERNEL_N = 96  # the reference kernel: a product of two fixed KERNEL_N x KERNEL_N matrices


def reference_rate(kernel: Callable[[], object] | None = None, rounds: int = 5, seconds: float = 0.3) -> float:
    """Calls of ``kernel`` (by default one KERNEL_N x KERNEL_N matrix product) per CPU-second of this thread:
    the median of ``rounds`` measurements of about ``seconds`` each."""
    if kernel is None:
        rng = np.random.default_rng(0)
        a, b = rng.standard_normal((KERNEL_N, KERNEL_N)), rng.standard_normal((KERNEL_N, KERNEL_N))
        kernel = lambda: a @ b  # noqa: E731
    kernel()  # a first call may build what later calls reuse (a payload's weights)
    rates = []
    for _ in range(rounds):
        n, start = 0, time.thread_time()
        while (spent := time.thread_time() - start) < seconds:
            kernel()
            n += 1
        rates.append(n / spent)
    return statistics.median(rates)


def payload_hz(cores: int, frequency: float, host_rate: float, device_rate: float) -> float:
    """A device's payload_hz: it serves a payload that took s CPU-seconds on the host in
    s x host_rate / device_rate seconds of its own, so cycles = s x cores x frequency x host_rate / device_rate."""
    return cores * frequency * host_rate / device_rate


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m node_runtime.model.calibrate",
                                description="Measure this machine's reference rate for payload calibration.")
    p.add_argument("--call", metavar="MODULE:FUNCTION",
                   help="time this payload, called as in a run with task id 0 and --args, instead of the "
                        "reference kernel: the most faithful ratio between two machines for that payload")
    p.add_argument("--args", type=json.loads, default={}, metavar="JSON",
                   help="keyword arguments of --call, as in the scenario's payload.args (a JSON object)")
    p.add_argument("--host-rate", type=float, metavar="R",
                   help="the rate measured on the machine that runs the emulation: also print this device's "
                        "payload_hz for --cores and --frequency")
    p.add_argument("--cores", type=int, default=1, help="the device's cores in the scenario (default 1)")
    p.add_argument("--frequency", type=float, help="the device's frequency in the scenario, cycles/s")
    args = p.parse_args(argv)
    if args.host_rate is not None and not (args.frequency and args.frequency > 0 and args.host_rate > 0
                                           and args.cores >= 1):
        p.error("--host-rate needs a rate > 0, --frequency > 0 and --cores >= 1")
    kernel, what = None, f"{KERNEL_N}x{KERNEL_N} matrix products"
    if args.call:
        try:
            extend_path([os.getcwd()])  # as ``python -m`` does for modules of the working directory
            fn = load(args.call, callable_ok=True)
        except PluginError as exc:
            p.error(f"--call: {exc}")
        kernel, what = (lambda: fn(0, **args.args)), f"calls of {args.call}"
    rate = reference_rate(kernel)
    print(f"reference rate: {rate:.6g} per CPU-second ({what}, median of 5)")
    if args.host_rate is not None:
        print(f"payload_hz: {payload_hz(args.cores, args.frequency, args.host_rate, rate):.6g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
