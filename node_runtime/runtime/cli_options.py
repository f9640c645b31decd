"""Command-line options that name a simulation on the bus, and the number types, defined once for
``orchestrator`` and ``zenohedge-node``, so that every command reads and checks them the same way: a bad
value is one ``error: argument --sim: expected … (got '…')`` line and exit status 2."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from typing import Any

from node_runtime.model.plugins import PluginError, is_import_path, load_from_command_line
from node_runtime.runtime.keys import CHUNK, DEFAULT_PREFIX
from node_runtime.runtime.security import Security, file_overrides
from node_runtime.runtime.zenoh_bus import ENDPOINT

# Seconds a command waits at most: past it, Zenoh's lease (milliseconds) and Python's waits overflow
MAX_TIMEOUT_S = 1e6


def builtin_or_import(names: Sequence[str], base: type) -> Callable[[str], str]:
    """One of ``names``, or the import path ("module:Class") of a user's subclass of ``base``, imported here
    so that a typo fails before any work (modules in the working directory are importable)."""

    def parse(text: str) -> str:
        if text in names:
            return text
        if not is_import_path(text):
            raise argparse.ArgumentTypeError(f"expected one of {', '.join(names)} or an import path "
                                             f"'module:Class' (got {text!r})")
        try:
            load_from_command_line(text, base)
        except PluginError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
        return text
    return parse


def integer(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """An integer >= ``minimum`` (and <= ``maximum``)."""
    expected = f"an integer >= {minimum}" if maximum is None else f"an integer from {minimum} to {maximum}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected} (got {text!r})") from None
        if value < minimum or (maximum is not None and value > maximum):
            raise argparse.ArgumentTypeError(f"expected {expected} (got {text!r})")
        return value
    return parse


def number(minimum: float, *, strict: bool, maximum: float = math.inf) -> Callable[[str], float]:
    """A finite number > ``minimum`` (``strict``) or >= ``minimum``, and <= ``maximum``."""
    expected = f"a number {'>' if strict else '>='} {minimum:g}"
    if maximum < math.inf:
        expected += f" and <= {maximum:g}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value) or value < minimum or (strict and value == minimum) or value > maximum:
            raise argparse.ArgumentTypeError(f"expected {expected} (got {text!r})")
        return value
    return parse


TIMEOUT = number(0, strict=True, maximum=MAX_TIMEOUT_S)


def endpoint(text: str) -> str:
    """``type=`` of an option holding a Zenoh endpoint."""
    if not ENDPOINT.match(text):
        raise argparse.ArgumentTypeError(f"expected an endpoint such as tcp/10.0.0.1:7447 (got {text!r})")
    return text


def sim_id(text: str) -> str:
    """``type=`` of an option holding a simulation id (one key chunk)."""
    if not CHUNK.match(text):
        raise argparse.ArgumentTypeError(f"expected letters, digits, '_', '.' or '-' (got {text!r})")
    return text


def prefix(text: str) -> str:
    """``type=`` of ``--prefix``: key chunks, without wildcards."""
    if not all(CHUNK.match(chunk) for chunk in text.split("/")):
        raise argparse.ArgumentTypeError(f"expected key chunks without wildcards, such as zedge (got {text!r})")
    return text


def add_sim_options(parser: argparse.ArgumentParser, *, required: bool, connect_help: str, sim_help: str) -> None:
    """``--connect ENDPOINT``, ``--sim ID`` and ``--prefix``: which simulation, behind which router."""
    parser.add_argument("--connect", metavar="ENDPOINT", type=endpoint, required=required, help=connect_help)
    parser.add_argument("--sim", metavar="ID", type=sim_id, required=required, help=sim_help)
    parser.add_argument("--prefix", type=prefix, default=DEFAULT_PREFIX,
                        help=f"key prefix of the simulation (default {DEFAULT_PREFIX})")


def add_security_options(parser: argparse.ArgumentParser, *, identity: str, config_help: str) -> None:
    """``--security DIR`` (TLS, mutual, and a Zenoh login; deploy/README.md) and ``--zenoh-config FILE``."""
    parser.add_argument("--security", metavar="DIR",
                        help=f"TLS with client certificates and a Zenoh login from DIR (ca.pem, cert.pem, key.pem, "
                             f"credentials), e.g. the {identity} directory written by deploy/make-certs.sh; "
                             "endpoints are then tls/HOST:PORT")
    parser.add_argument("--zenoh-config", metavar="FILE", help=config_help)


def security_options(args: argparse.Namespace) -> tuple[Security | None, dict[str, Any] | None]:
    """The parsed ``--security`` and ``--zenoh-config``; raises SecurityError (one line) on bad files."""
    security = Security.from_dir(args.security) if args.security else None
    return security, file_overrides(args.zenoh_config) if args.zenoh_config else None
