"""Position traces of moving nodes: a CSV of timed positions (``t,node,x,y``) or SUMO's FCD output, read into
each node's samples (seconds, x, y) for ``node_runtime.model.mobility.Trace``."""

from __future__ import annotations

import csv
import math
from itertools import pairwise
from pathlib import Path
from xml.etree.ElementTree import ParseError

Samples = dict[str, list[tuple[float, float, float]]]  # per node (or vehicle): (seconds, x, y) in time order
TRACE_COLUMNS = ["t", "node", "x", "y"]


class MobilityError(ValueError):
    """A position trace that cannot be read: one line naming the file (and the line) and what was expected."""


def read_trace(path: Path) -> Samples:
    """A CSV with the header ``t,node,x,y``: seconds from the episode start, a node id, metres."""
    samples: Samples = {}
    try:
        with path.open(newline="") as fh:
            reader = csv.DictReader(fh)
            if reader.fieldnames is None or [c.strip() for c in reader.fieldnames] != TRACE_COLUMNS:
                raise MobilityError(f"{path}: expected the header {','.join(TRACE_COLUMNS)}")
            for line, rec in enumerate(reader, start=2):
                try:
                    t, x, y = float(rec["t"]), float(rec["x"]), float(rec["y"])
                    node = rec["node"].strip()
                except (TypeError, ValueError, AttributeError):
                    raise MobilityError(f"{path}:{line}: expected numbers t, x and y and a node id") from None
                if not all(math.isfinite(v) for v in (t, x, y)) or t < 0:
                    raise MobilityError(f"{path}:{line}: expected t >= 0 and finite t, x and y")
                samples.setdefault(node, []).append((t, x, y))
    except FileNotFoundError:
        raise MobilityError(f"file not found: {path}") from None
    except UnicodeDecodeError:
        raise MobilityError(f"{path}: not a text file (expected a CSV of positions)") from None
    except csv.Error as exc:
        raise MobilityError(f"{path}: not a CSV file: {exc}") from None
    except OSError as exc:
        raise MobilityError(f"{path}: cannot read it: {exc.strerror}") from None
    return {node: ordered(path, node, rows) for node, rows in samples.items()}


def read_fcd(path: Path) -> Samples:
    """SUMO's floating car data (``sumo --fcd-output``), read through sumolib: each vehicle's x and y at
    each ``timestep`` it appears in."""
    try:
        import sumolib.xml
    except ImportError:
        raise MobilityError(f"{path}: reading SUMO FCD output needs sumolib (pip install sumolib)") from None
    if not path.is_file():
        raise MobilityError(f"file not found: {path}")
    samples: Samples = {}
    try:
        for step in sumolib.xml.parse(str(path), "timestep"):
            t = float(step.time)
            for vehicle in step.vehicle or ():
                samples.setdefault(vehicle.id, []).append((t, float(vehicle.x), float(vehicle.y)))
    except ParseError as exc:
        raise MobilityError(f"{path}: not an XML file: {exc}") from None
    except (TypeError, ValueError, AttributeError):
        raise MobilityError(f"{path}: expected SUMO FCD output (<timestep time=…> of <vehicle id=… x=… "
                            "y=…>)") from None
    return {vehicle: ordered(path, vehicle, rows) for vehicle, rows in samples.items()}


def ordered(path: Path, node: str, rows: list[tuple[float, float, float]]) -> list[tuple[float, float, float]]:
    rows = sorted(rows)
    for a, b in pairwise(rows):
        if a[0] == b[0]:
            raise MobilityError(f"{path}: {node!r} has two positions at t = {a[0]:g}")
    return rows
