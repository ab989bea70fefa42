"""Runs on a Dask distributed cluster: the campaign's workers without its file system.

``cellsim campaign --scheduler tcp://HOST:PORT`` (and ``falsify``) submit each run to
a Dask scheduler instead of the local pool. A worker shares nothing with the
campaign but the scheduler:

* **inputs**: the campaign's snapshot (``OUT/inputs``) is read once, as bytes, and
  travels with each run (tens of kilobytes for the shipped cells). A worker writes it
  once into its own local directory, named by the SHA-256 of its content
  (``<worker dir>/cellsim-inputs/<digest>``), and every run it is given is made from
  there. Not scattered: data scattered under its files' names was shared by every
  campaign on the scheduler (an audit saw one campaign run another's scenario), and
  lost with the last worker holding it (the campaign then failed where it retries).
* **outputs**: the worker simulates and checks the run in a scratch folder of its
  own, exactly as a local worker does (:func:`cellsim.campaign.engine.execute_run`),
  and returns the run folder's files. The campaign writes them under
  ``OUT/runs/NNNN``, ``result.json`` last, as a local run does: resume, content
  identity and provenance work the same way.
* **a worker that dies**: the scheduler hands its runs to another worker (a run
  is a pure function of the campaign and its index, so a retry gives the same
  run). Each run is written once, when its result comes back. How many runs
  were retried (the scheduler's count of workers lost while running them) is
  recorded in results.json (``cluster.retries``) and the report.

Start a cluster with ``dask scheduler`` and ``dask worker`` (docs/cluster.md) or
dask-jobqueue on Slurm. Each worker needs cellsim installed, at the campaign's
version (the campaign refuses workers of another).
"""

from __future__ import annotations

import concurrent.futures
import hashlib
import math
import os
import shutil
import threading
import uuid
from pathlib import Path

from cellsim.atomic import write_text

CACHE = "cellsim-inputs"
SCRATCH = "cellsim-runs"
CONNECT_TIMEOUT = 10.0
"""Seconds to reach the scheduler before giving up, unless ``CELLSIM_SCHEDULER_TIMEOUT`` says otherwise
(:func:`connect_timeout`)."""


def connect_timeout() -> float:
    """Seconds to reach the scheduler: ``CELLSIM_SCHEDULER_TIMEOUT`` (a slow link may need more, a test less), else
    :data:`CONNECT_TIMEOUT`; a value that is no positive number is a ClusterError naming it."""
    text = os.environ.get("CELLSIM_SCHEDULER_TIMEOUT")
    if text is None:
        return CONNECT_TIMEOUT
    try:
        seconds = float(text)
    except ValueError:
        seconds = float("nan")
    if not (math.isfinite(seconds) and seconds > 0):
        raise ClusterError(f"CELLSIM_SCHEDULER_TIMEOUT={text}: expected seconds above 0")
    return seconds


class ClusterError(Exception):
    """The cluster cannot be used: unreachable, no workers, or workers of another cellsim."""


def check_reachable(address: str, timeout: float | None = None) -> None:
    """Fail, before a campaign touches its folder, unless a Dask scheduler answers at ``address`` within
    ``timeout`` seconds: asked who it is over Dask's own protocol (a port that merely accepts connections,
    or answers in another protocol, is no scheduler; the connection alone has no limit on its handshake)."""
    import asyncio
    import socket

    from distributed.core import rpc

    timeout = connect_timeout() if timeout is None else timeout

    host, _, port = address.split("://", 1)[-1].rpartition(":")
    try:  # nothing listening: said at once (Dask's own connect would retry until the timeout)
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except (OSError, ValueError) as e:
        raise ClusterError(f"cannot reach the Dask scheduler at {address}: {e}") from None

    async def identity():
        async with rpc(address, timeout=timeout) as scheduler:
            return await scheduler.identity()

    try:
        answer = asyncio.run(asyncio.wait_for(identity(), timeout))
    except (asyncio.TimeoutError, TimeoutError):
        raise ClusterError(f"no Dask scheduler answered at {address} within {timeout:g} s") from None
    except Exception as e:  # noqa: BLE001 - refused, reset, garbage: distributed raises many kinds
        raise ClusterError(f"cannot reach the Dask scheduler at {address}: {' '.join(str(e).split())[:200] or type(e).__name__}") from None
    if not isinstance(answer, dict) or answer.get("type") != "Scheduler":
        raise ClusterError(f"{address} answers, but not as a Dask scheduler")


def read_snapshot(folder: Path) -> tuple[str, dict[str, bytes]]:
    """Every file under ``folder`` as ``{relative path: bytes}``, and the SHA-256 of them all."""
    files = {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}
    digest = hashlib.sha256()
    for name, data in files.items():
        digest.update(name.encode() + b"\0" + hashlib.sha256(data).digest())
    return digest.hexdigest(), files


def _remap(text: str, old: str, new: str) -> str:
    """A path (or an override naming one) under the campaign's inputs, moved to the worker's copy."""
    return text.replace(old, new)


def run_remotely(execute_run, plan, inputs_dir: str, digest: str, snapshot: dict[str, bytes], index: int, origin,
                 configuration, search, version: dict) -> tuple[dict, dict[str, bytes]]:
    """On a worker: run ``index`` from the snapshot (``execute_run``: the campaign's); returns its result and
    its folder's files. ``version``: the campaign's :func:`cellsim.provenance.simulator_versions`."""
    import dataclasses

    from distributed import get_worker

    from cellsim.provenance import simulator_versions

    mine = simulator_versions()
    if not isinstance(version, dict):  # a campaign of a cellsim that sent its own version alone
        version = {"cellsim": str(version)}
    for package in mine:  # a run's numbers depend on each: a worker must have the campaign's own
        if mine[package] != version.get(package):
            raise ClusterError(f"worker {get_worker().address} has {package} {mine[package]}, the campaign "
                               f"{version.get(package)}")
    base = Path(get_worker().local_directory)
    cache = base / CACHE / digest
    if not cache.is_dir():
        staging = base / CACHE / f".{digest}.{uuid.uuid4().hex}"
        for name, data in snapshot.items():
            path = staging / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        try:
            staging.rename(cache)
        except OSError:  # another thread of this worker got there first
            shutil.rmtree(staging, ignore_errors=True)
    local = dataclasses.replace(
        plan,
        scenario=_remap(plan.scenario, inputs_dir, str(cache)),
        overrides=tuple(_remap(o, inputs_dir, str(cache)) for o in plan.overrides),
    )
    scratch = base / SCRATCH / uuid.uuid4().hex
    try:
        result = execute_run(local, scratch, index, origin, configuration, search)
        folder = scratch / result["out"]
        files = {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return result, files


def write_run_files(folder: Path, files: dict[str, bytes], last: str) -> None:
    """A remote run's files written into ``folder``, ``last`` (its result, whose presence marks it done) last."""
    if folder.exists():
        shutil.rmtree(folder)  # an unfinished earlier attempt
    for name, data in files.items():
        if name != last:
            path = folder / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
    if last in files:
        write_text(folder / last, files[last].decode("utf-8"))


class ClusterPool:
    """``submit(execute_run, plan, out, index, ...)`` onto a Dask cluster, with the local pool's futures.

    The futures are :class:`concurrent.futures.Future` resolving to the run's result
    once its files are written under ``out``; each is running from the start (never cancelled).
    """

    def __init__(self, address: str, inputs_dir: Path, result_name: str):
        try:
            from distributed import Client
        except ImportError as e:  # pragma: no cover - distributed is a dependency
            raise ClusterError(f"--scheduler needs the distributed package ({e})") from None
        from cellsim.provenance import simulator_versions

        try:
            self.client = Client(address, timeout=connect_timeout(), set_as_default=False)
        except (OSError, TimeoutError) as e:
            raise ClusterError(f"cannot reach the Dask scheduler at {address}: {e}") from None
        self.address = address
        self.result_name = result_name
        self.version = simulator_versions()
        self.inputs_dir = str(inputs_dir.resolve())
        self.digest, snapshot = read_snapshot(inputs_dir)
        self.snapshot = snapshot  # (sent with each run: see the module docstring)
        self._tasks: list = []
        self._lock = threading.Lock()

    def submit(self, execute_run, plan, out: Path, index: int, origin=None, configuration=None, search=None):
        """Run ``execute_run(plan, <scratch>, index, origin, configuration, search)`` on a worker. The future is
        running from the start (the campaign hands a cluster no more runs than it has slots: each starts at once),
        so, as with a local pool, a run once handed over cannot be cancelled: it finishes and is kept."""
        future: concurrent.futures.Future = concurrent.futures.Future()
        future.set_running_or_notify_cancel()
        task = self.client.submit(run_remotely, execute_run, plan, self.inputs_dir, self.digest, self.snapshot, index,
                                  origin, configuration, search, self.version, pure=False,
                                  key=f"cellsim-run-{index}-{uuid.uuid4().hex}")
        with self._lock:
            self._tasks.append(task)

        def done(task_future) -> None:
            try:
                result, files = task_future.result()
                write_run_files(Path(out) / result["out"], files, self.result_name)
            except BaseException as e:  # noqa: BLE001 - handed to whoever waits on the future, as one line
                future.set_exception(e if isinstance(e, ClusterError) else
                                     ClusterError(f"run {index} failed on the cluster ({type(e).__name__}: {e})"))
                return
            future.set_result(result)

        task.add_done_callback(done)
        return future

    def retries(self) -> int:
        """Runs handed to another worker after the one running them was lost (the scheduler's count)."""
        keys = [t.key for t in self._tasks]

        def count(dask_scheduler, keys=keys) -> int:
            return sum(ts.suspicious for key in keys if (ts := dask_scheduler.tasks.get(key)) is not None)

        return int(self.client.run_on_scheduler(count))

    def workers(self) -> int:
        return len(self.client.scheduler_info(n_workers=-1).get("workers", {}))

    def slots(self) -> int:
        """Runs the cluster can run at once now: its workers' threads (at least one, while none has joined)."""
        return max(1, sum(self.client.nthreads().values()))

    def close(self) -> None:
        self.client.close()
