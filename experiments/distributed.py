"""The independent runs of an experiment as Ray tasks: on a local Ray started here (``--ray``) or on an
existing cluster (``--ray-address HOST:PORT`` or ``auto``). Ray is optional: ``pip install -e ".[sweep]"``.

Each run is one task that declares the CPUs it needs (``--cpus-per-run``) and writes its files into a
scratch directory on whichever machine runs it; the files come back with its result and land under the
driver's output directory, so that the outputs are those of a local run. Workers on a cluster need this
project installed (the same version)."""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from experiments.common import positive_int, positive_number

Job = TypeVar("Job")
Result = TypeVar("Result")
Files = dict[str, bytes]


def add_ray_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("distributed runs (Ray, optional: pip install -e '.[sweep]')")
    g.add_argument("--ray", action="store_true", help="run every run as a task on a local Ray started for this run")
    g.add_argument("--ray-address", default=None, metavar="HOST:PORT",
                   help="run on this existing Ray cluster instead ('auto': the one this machine belongs to)")
    g.add_argument("--ray-cpus", type=positive_int, default=None,
                   help="CPUs of the local Ray of --ray (default: all of this machine's)")
    g.add_argument("--cpus-per-run", type=positive_number, default=1.0,
                   help="CPUs each run declares to Ray (default 1; may be a fraction)")


def wants_ray(args: argparse.Namespace) -> bool:
    return bool(args.ray or args.ray_address)


def ray_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with the Ray options, as one line for the user; None when they can be followed."""
    if args.ray_cpus is not None and not args.ray:
        return "--ray-cpus sizes the local Ray of --ray"
    if not wants_ray(args):
        return None
    if args.ray and args.ray_address:
        return "--ray starts a local Ray, --ray-address joins a running one: give one of them"
    try:
        import ray  # noqa: F401
    except ImportError:
        return "--ray and --ray-address need Ray: python -m pip install -e '.[sweep]'"
    return None


def run_on_ray(run: Callable[[Job, Path], Result], jobs: Sequence[Job], out: Path, args: argparse.Namespace,
               label: Callable[[Job], str] = str) -> list[Result]:
    """``run(job, directory)`` for every job as a Ray task; the files each writes land under ``out``.

    Results come back in the order of ``jobs``, whatever order the tasks finish in. Ray is shut down on
    the way out, also after an error, so that none of its processes outlive the command."""
    import ray

    if args.ray_address:
        ray.init(address=args.ray_address)
    else:
        ray.init(num_cpus=args.ray_cpus, include_dashboard=False)
    try:
        task = ray.remote(num_cpus=args.cpus_per_run)(_in_scratch_directory)
        refs = [task.remote(run, job) for job in jobs]
        index = {ref: i for i, ref in enumerate(refs)}
        results: list[Any] = [None] * len(jobs)
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            i = index[done[0]]
            results[i], files = ray.get(done[0])
            for name, data in files.items():
                (out / name).parent.mkdir(parents=True, exist_ok=True)
                (out / name).write_bytes(data)
            print(f"[{len(jobs) - len(pending)}/{len(jobs)}] {label(jobs[i])} done", flush=True)
        return results
    finally:
        ray.shutdown()


def _in_scratch_directory(run: Callable[[Job, Path], Result], job: Job) -> tuple[Result, Files]:
    with tempfile.TemporaryDirectory(prefix="zenohedge-run-") as scratch:
        result = run(job, Path(scratch))
        files = {str(p.relative_to(scratch)): p.read_bytes() for p in sorted(Path(scratch).rglob("*")) if p.is_file()}
    return result, files
