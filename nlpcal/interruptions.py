"""Ctrl-C and SIGTERM held back where the exception they raise would be lost or harmful.

Python runs a signal's handler in the main thread between two bytecodes, wherever that is, and
the handler raises there: KeyboardInterrupt for Ctrl-C, the command line's `Terminated` for
SIGTERM. Two kinds of place in nlpcal cannot take that exception:

- building a CasADi problem (`nlpcal.nlp.solver.problem`): CasADi's SWIG wrappers look at each
  argument of a symbolic operation with the C API's hasattr, which runs Python code (the
  `shape` property of an SX or MX) and drops any exception raised inside it: silently before
  Python 3.13, with an "Exception ignored" report since. A Ctrl-C there was lost, and the run
  went on to the end;
- starting a dask.distributed LocalCluster (`nlpcal.cluster`): interrupted inside its
  constructor, it is left half made, and its closing at exit fails with a traceback.

`deferred` holds the signals for such a block and acts on them as it ends. `held` blocks them
in a thread, so that the worker processes it starts never see them (`nlpcal.cluster`): this
process handles them and ends its workers.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable

#: The signals whose Python handlers `deferred` holds back.
SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def deferred(second_acts: bool = False):
    """SIGINT and SIGTERM, where Python handles them, handled as their handlers say on leaving
    the block rather than inside it (the first one caught).

    second_acts : a second signal inside the block has the first one handled at once (a start
        that hangs can still be interrupted); else every one waits for the end of the block.

    Nothing is held outside the main thread (Python runs handlers there only), nor for a signal
    whose handler Python does not run (SIG_DFL, SIG_IGN, or one not set from Python).
    """
    handlers: dict[int, Callable] = {}
    for held in SIGNALS:
        handler = signal.getsignal(held)
        if callable(handler):
            handlers[held] = handler
    if threading.current_thread() is not threading.main_thread() or not handlers:
        yield
        return
    caught: list[int] = []

    def restore() -> None:
        for number, handler in handlers.items():
            signal.signal(number, handler)

    def defer(number, frame) -> None:
        if second_acts and caught:  # the first signal's handler, here and now
            first = caught.pop()
            restore()
            handlers[first](first, frame)
            return
        if not caught:
            caught.append(number)

    for number in handlers:
        signal.signal(number, defer)
    try:
        yield
    finally:
        restore()
        if caught:  # called, not raised again: this thread may hold the signal blocked
            handlers[caught[0]](caught[0], None)


@contextlib.contextmanager
def held(numbers=(signal.SIGINT,)):
    """The signals `numbers` (SIGINT: a Ctrl-C) held back (blocked) in this thread inside. The
    processes it starts, and the threads it starts and theirs, inherit that: a worker process
    started so never sees what a terminal or a `kill` of the process group sends to every
    process of the group, which would have it print a traceback (also as it starts, before any
    code of its own could ignore it) or die as it writes a result; this process handles the
    signal and ends its workers. A signal meanwhile reaches this process through another
    thread, or on leaving. Nothing where signals cannot be blocked (Windows).

    multiprocessing's resource tracker is started first: it unblocks SIGINT in the thread that
    starts it (a cluster's, otherwise), after holding it for the tracker."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    before = signal.pthread_sigmask(signal.SIG_BLOCK, set(numbers))
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)
