"""Where Dask work runs: the schedulers of `--scheduler`, and many tasks run on one of them.

    threads, processes   Dask's own schedulers in this process: a pool of threads, or of
                         processes (one per core)
    local                a dask.distributed LocalCluster of this machine: one single-threaded
                         worker process per core (or `workers`)
    ADDRESS              the scheduler of a running cluster: tcp://host:8786, or the path of the
                         JSON file a scheduler wrote with --scheduler-file
    a Client             a dask.distributed Client the caller made

Without a scheduler nothing here imports Dask: the in-process path stays the default. Dask and
dask.distributed are the `dask` extra (pip install 'nlpcal[dask]').
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import socket
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from . import chunks, interruptions, validation
from .errors import InputError
from .results import read_json_document

#: Scheduler names of `--scheduler`; anything else is the address of a running scheduler.
SCHEDULERS = ("threads", "processes", "local")
INSTALL_DASK = "pip install 'nlpcal[dask]'"
#: glibc's allocator settings of the workers of a "local" cluster, set before they start.
#: dask.distributed sets MALLOC_TRIM_THRESHOLD_ to 64 KiB, which also fixes glibc's mmap
#: threshold at 128 KiB: every chunk-sized temporary of a pass is then mapped and unmapped, and a
#: Table 1 pass runs four times slower (docs/scale.md). These keep such temporaries on the heap.
WORKER_MALLOC = {"MALLOC_TRIM_THRESHOLD_": 32 * 2**20, "MALLOC_MMAP_THRESHOLD_": 16 * 2**20}
#: Seconds to wait for a running scheduler to answer. [s]
CONNECT_TIMEOUT_S = 30


def _require(module: str, what: str):
    try:
        return __import__(module, fromlist=["_"])
    except ImportError:
        raise InputError(f"{what} needs {module.split('.')[0]}: {INSTALL_DASK}") from None


def is_client(value) -> bool:
    """Whether `value` is a dask.distributed Client."""
    return type(value).__name__ == "Client" and type(value).__module__.startswith("distributed")


def describe(spec) -> str:
    """A scheduler for a message: its name, or what it is."""
    if spec is None:
        return "this process"
    if is_client(spec):
        return f"the Dask cluster at {spec.scheduler.address}"
    if spec in ("threads", "processes"):
        return f"Dask's {spec} scheduler"
    if spec == "local":
        return "a local Dask cluster"
    return f"the Dask cluster at {spec}"


@contextlib.contextmanager
def scheduler(spec=None, workers: int | None = None):
    """Run the Dask work inside on `spec` (see the module's doc); yields None (no scheduler: the
    in-process path), the name of a local scheduler, or a distributed Client.

    workers : worker processes of "local" or "processes" (default: one per core).
    """
    workers = validation.optional_whole(workers, "workers")
    if spec is None:
        yield None
        return
    check_spec(spec, workers)
    dask = _require("dask", f"--scheduler {spec}")
    if is_client(spec):
        with dask.config.set(scheduler=spec):
            yield spec
        return
    if spec == "threads":
        with dask.config.set(scheduler=spec):
            yield spec
        return
    if spec == "processes":  # one pool for every pass: each process imports nlpcal once
        from dask.multiprocessing import get_context

        pool = _WorkerPool(workers, mp_context=get_context(), initializer=blas_one_thread)
        try:
            with dask.config.set(scheduler=spec, pool=pool):
                yield spec
        finally:  # interrupted: the tasks under way end, those waiting do not start
            pool.shutdown(wait=True, cancel_futures=True)
        return
    distributed = _require("distributed", f"--scheduler {spec}")
    with contextlib.ExitStack() as stack:
        stack.callback(logging.disable, logging.root.manager.disable)  # last: as it was
        if spec == "local":
            stack.enter_context(worker_environment(dask))
            # the thread that starts (and restarts) the workers inherits the held SIGINT; a
            # signal meanwhile waits for the start to end: interrupted inside its constructor,
            # the cluster is left half made. A second acts at once (a start that hangs): a
            # SIGTERM always, a SIGINT (held in this thread) once a thread of the process that
            # does not hold it receives it, as BLAS's threads do, else as the start ends
            with interruptions.deferred(second_acts=True), interruptions.held():
                cluster = stack.enter_context(
                    distributed.LocalCluster(
                        n_workers=workers,
                        threads_per_worker=1,
                        processes=True,
                        dashboard_address=None,
                        # the scheduler's HTTP server (no dashboard) on a free port: on its
                        # default, 8787, another cluster there would have Dask warn on stderr
                        scheduler_kwargs={"dashboard_address": ":0"},
                        preload=[__name__],  # `dask_setup` in each worker
                    )
                )
                client = stack.enter_context(distributed.Client(cluster, set_as_default=False))
        else:
            client = stack.enter_context(_connect(distributed, str(spec)))
        client.loop.asyncio_loop.set_exception_handler(exit_unreported)
        stack.push(unlogged_if_interrupted)  # the first out: before the Client and cluster close
        # the default for the work inside (Dask's scheduler, the Client of its futures),
        # undone however that work ends
        with client.as_current():
            yield client


def unlogged_if_interrupted(kind, error, traceback) -> bool:
    """An exit callback: all logging off for the rest of the ExitStack when the block ends by
    an interruption (Ctrl-C, or the command line's SIGTERM), which the caller states itself:
    dask.distributed logs the tasks that the workers it closes lose."""
    if kind is not None and issubclass(kind, KeyboardInterrupt):
        logging.disable(logging.CRITICAL)
    return False


def exit_unreported(loop, context: dict) -> None:
    """The exception handler of a Client's event loop: asyncio's handling, but no report of a
    task that ended with dask.distributed's AllExit, unretrieved. The gather of an interrupted
    computation leaves such tasks behind, and asyncio reports each with a traceback when it is
    collected, which may be before or after the interruption reaches the caller."""
    if type(context.get("exception")).__name__ != "AllExit":
        loop.default_exception_handler(context)


#: The share of its memory a Dask scheduler may give a log read from files, kept there for the
#: later passes of a calibration (`nlpcal.io.lazy.read_lazy_log`): half, below the 60 % of its
#: limit at which a dask.distributed worker starts to move data to disk.
KEEP_SHARE = 0.5


def memory_to_keep() -> tuple | None:
    """(bytes, where) a log read from its files may take in memory on the current Dask
    scheduler, kept there for the later passes of a calibration, or None where it is not kept.

    On a dask.distributed cluster: KEEP_SHARE of a worker's memory limit less what the worker
    holds, for the worker with the least of it, times the number of workers (Dask places the
    blocks where it likes); nothing when a worker has no limit, or the scheduler answers
    with an error. On this process's own schedulers (threads, synchronous, and Dask's default
    for arrays): KEEP_SHARE of the memory available here (`nlpcal.chunks.available_memory`).
    Nothing on any
    other scheduler (Dask's processes, or an executor: every pass would send each block to a
    process again). [byte]
    """
    import dask.local
    import dask.threaded
    from dask.base import get_scheduler

    get = get_scheduler()
    owner = getattr(get, "__self__", None)
    if is_client(owner):
        workers = _workers(owner)
        if not workers or any(not w.get("memory_limit") for w in workers):
            return None
        least = min(
            KEEP_SHARE * w["memory_limit"] - w.get("metrics", {}).get("memory", 0) for w in workers
        )
        return max(0.0, least) * len(workers), f"the workers of {describe(owner)}"
    if get not in (None, dask.threaded.get, dask.local.get_sync):
        return None
    available = chunks.available_memory()
    return None if available is None else (KEEP_SHARE * available, "this machine")


def _workers(client) -> list:
    """The workers' information of a Client's scheduler (all of them: newer dask.distributed
    reports five unless asked for more); none when the scheduler answers with an error (the
    passes then meet whatever is wrong with it; one that does not answer holds them alike)."""
    try:
        try:
            info = client.scheduler_info(n_workers=-1)
        except TypeError:  # dask.distributed before 2025
            info = client.scheduler_info()
        return list(info.get("workers", {}).values())
    except Exception:  # a scheduler that is gone, or answers in another form
        return []


def worker_environment(dask):
    """The Dask setting under which new workers start with WORKER_MALLOC."""
    key = "distributed.nanny.pre-spawn-environ"
    return dask.config.set({key: {**dask.config.get(key, {}), **WORKER_MALLOC}})


def dask_setup(worker) -> None:
    """Run by each worker of a "local" cluster as it starts (a Dask preload of this module):
    its log leaves out the tasks that refused the data (`refusal_unlogged`) and what it meets
    as the cluster closes under it (`closing_unlogged`), which nlpcal reports itself, in one
    line, on the same terminal."""
    logging.getLogger("distributed.worker").addFilter(refusal_unlogged)
    for name in ("distributed.worker", "distributed.worker.state_machine"):
        logging.getLogger(name).addFilter(closing_unlogged)


def refusal_unlogged(record: logging.LogRecord) -> bool:
    """False for a dask.distributed worker's "Compute Failed" record of a task that raised
    nlpcal's InputError (a value the log's reader refused: the error the command line then
    states); True, logged as Dask logs it, for any other failure."""
    message = record.getMessage()
    return not (message.startswith("Compute Failed") and "InputError(" in message)


class _WorkerPool(ProcessPoolExecutor):
    """The pool of "processes": it starts its worker processes as tasks are submitted, with
    SIGINT held (`interruptions.held`), and SIGTERM too where this process handles it (the command
    line does): a worker that a SIGTERM to the process group ended as it wrote its result left
    the pool's reader waiting for the rest of it, and the command hung; this process ends the
    pool instead, once the tasks under way end. Where SIGTERM ends this process at once (its
    default), it ends the workers too."""

    def submit(self, fn, /, *args, **kwargs):
        handled = callable(signal.getsignal(signal.SIGTERM))
        with interruptions.held((signal.SIGINT, signal.SIGTERM) if handled else (signal.SIGINT,)):
            return super().submit(fn, *args, **kwargs)


def closing_unlogged(record: logging.LogRecord) -> bool:
    """False for what a worker of a local cluster logs as the cluster closes under it: a task
    cancelled as it ran, a heartbeat that found the scheduler gone (with a traceback). nlpcal
    closes its cluster midway only when interrupted, and says that itself."""
    message = record.getMessage()
    return not (
        message.endswith("ended with CancelledError")
        or message.startswith("Failed to communicate with scheduler during heartbeat")
    )


def blas_one_thread() -> None:
    """Hold BLAS to one thread in a worker process (the processes share the cores), when
    threadpoolctl is installed (dask.distributed sets its workers so by itself)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return
    threadpool_limits(limits=1, user_api="blas")


#: The most worker processes of "local" or "processes" per core available: more only share
#: the cores, each with its own memory (a worker takes 100-200 MiB), and a machine's worth of
#: them starves the scheduler's heartbeats. [1]
WORKERS_PER_CORE = 4
#: What a running scheduler's address looks like: protocol://host:port (tcp, tls, ws, wss,
#: ucx), or host:port (tcp).
ADDRESS = re.compile(
    r"(?:(?:tcp|tls|ws|wss|ucx)://)?(?:[^\s/:\[\]]+|\[[0-9a-fA-F:.]+(?:%[\w.-]+)?\])(?::\d+)?"
)


def check_spec(spec, workers: int | None) -> None:
    """InputError, at once, for a scheduler that is none of `scheduler`'s (a misspelt name would
    otherwise be tried as an address, and the Client left of it hold the exit for a minute),
    or more `workers` than WORKERS_PER_CORE per core available to this process."""
    if is_client(spec):
        return
    if isinstance(spec, os.PathLike):  # a scheduler file
        spec = os.fspath(spec)
    if not isinstance(spec, str):
        raise InputError(f"--scheduler: expected a name or an address, got {spec!r}")
    if spec.lower() in SCHEDULERS and spec not in SCHEDULERS:
        raise InputError(f"--scheduler {spec!r}: did you mean {spec.lower()!r}?")
    if spec not in SCHEDULERS and not _names_file(spec) and not ADDRESS.fullmatch(spec):
        raise InputError(
            f"--scheduler {spec!r}: neither {', '.join(SCHEDULERS)}, nor a scheduler's address "
            f"(tcp://host:8786) or scheduler file"
        )
    most = WORKERS_PER_CORE * chunks.available_cores()
    if spec in ("local", "processes") and workers is not None and workers > most:
        raise InputError(
            f"--workers {workers}: at most {most} worker processes ({WORKERS_PER_CORE} per core "
            f"this process may use); more would only share the cores, each with its own memory"
        )


def _connect(distributed, address: str):
    """A Client of a running scheduler, or InputError saying why there is none.

    The Client does not make itself Dask's default (`scheduler` sets it for the work inside):
    one that fails to connect would leave the default set to a cluster that is not there, and
    undo later whatever default was set when it is collected."""
    is_file = _names_file(address)
    if is_file and not Path(address).is_file():  # Dask would wait for it to appear
        raise InputError(f"{address}: no such scheduler file")
    target = scheduler_file_address(address) if is_file else address
    try:
        _reachable(target)  # before a Client: one that fails holds the exit for a minute
        return distributed.Client(target, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except Exception as exc:  # refused, timed out, or an answer that is not Dask's protocol
        choices = ", ".join(SCHEDULERS)
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(
            f"no Dask scheduler answers at {target!r} ({reason}); give its address "
            f"(tcp://host:8786), its scheduler file, or one of {choices}"
        ) from None


def _names_file(spec: str) -> bool:
    """Whether `--scheduler` names a scheduler file (a .json path, or any file there is)."""
    return spec.endswith(".json") or Path(spec).is_file()


def _reachable(address: str) -> None:
    """OSError unless a TCP connection opens to the host and port of a scheduler's address
    (Dask's default port 8786 when it has none) within CONNECT_TIMEOUT_S: a host that is not
    known or a port nobody listens on is told at once. UCX addresses are left to Dask."""
    from distributed.comm.addressing import parse_address, parse_host_port

    protocol, location = parse_address(address)
    if protocol == "ucx":
        return
    host, port = parse_host_port(location, default_port=8786)
    socket.create_connection((host, port), timeout=CONNECT_TIMEOUT_S).close()


def scheduler_file_address(path: str) -> str:
    """The scheduler's address in a scheduler file (the JSON a scheduler writes with
    --scheduler-file: an object whose "address" is "protocol://host:port")."""
    document = read_json_document(path, "scheduler file")
    address = document.get("address") if isinstance(document, dict) else None
    if not isinstance(address, str) or not re.fullmatch(r"[a-z][a-z0-9+]*://\S+", address):
        raise InputError(
            f'{path}: not a Dask scheduler file (expected a JSON object whose "address" is '
            f"protocol://host:port, as a scheduler started with --scheduler-file writes)"
        )
    return address


def run_tasks(function, items, on_result, client=None) -> None:
    """function(item) for every item, on_result(item, result) as each one finishes (in this
    process, in the order they finish).

    client : None (one after another in this process), "threads" or "processes" (Dask's own
    schedulers) or a dask.distributed Client. A task that raises (its worker died, say) gives
    on_result(item, the exception).
    """
    items = list(items)
    if client is None:
        for item in items:
            on_result(item, function(item))
        return
    if is_client(client):
        _run_distributed(function, items, on_result, client)
        return
    dask = _require("dask", "a Dask scheduler")
    from dask.callbacks import Callback

    keys = {f"nlpcal-task-{k}": item for k, item in enumerate(items)}

    def finished(key, result, dsk, state, worker_id):
        if key in keys:
            on_result(keys[key], result)

    tasks = [
        dask.delayed(function, pure=False)(item, dask_key_name=key) for key, item in keys.items()
    ]
    with Callback(posttask=finished):
        dask.compute(*tasks, scheduler=client)


def _run_distributed(function, items, on_result, client) -> None:
    from distributed import as_completed

    futures = client.map(function, items, pure=False)
    item_of = {future.key: item for future, item in zip(futures, items)}
    for future in as_completed(futures):
        try:
            result = future.result()
        except Exception as exc:  # the task's worker died, or it could not be sent
            result = exc
        on_result(item_of[future.key], result)
        future.release()
