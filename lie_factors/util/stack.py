"""Run GTSAM's recursive calls on a thread with a large stack.

GTSAM's elimination (the elimination tree / Bayes tree it builds and walks for
every linear solve: LM, Gauss–Newton, ``GaussianFactorGraph.optimize``,
``InitializePose3``, ``lago``) recurses once per level of the tree, and on a
chain the tree is as deep as the chain is long.  On the main thread's default
8 MiB stack a 100k-pose SE(3) chain dies with SIGSEGV.  :func:`call` runs the
call on a worker thread whose stack is :data:`STACK_BYTES` (address space
only: pages are committed as the recursion touches them, so an unused stack
costs no memory) and waits for it.

Size: measured on generated SE(3) chains (benchmarks/generate_posegraph.py
``--closure-every 0``), GTSAM 4.3, x86-64: see :data:`STACK_BYTES`.
"""

from __future__ import annotations

import threading
from typing import Callable, TypeVar

T = TypeVar("T")

#: Stack of the worker thread.  GTSAM's recursion (``InitializePose3.initialize``, an LM
#: iteration's elimination) needs stack in proportion to a chain's length, and a
#: 100k-pose SE(3) chain overflows the default 8 MiB (tests/util/test_stack.py); this is
#: reserved address space, committed only as the recursion touches it, so it can be
#: far larger than any chain needs.
STACK_BYTES = 1 << 30

_local = threading.local()


def call(func: Callable[..., T], *args, **kwargs) -> T:
    """``func(*args, **kwargs)`` on a thread with a :data:`STACK_BYTES` stack; its result or its exception.

    Exceptions (``KeyboardInterrupt`` and ``SystemExit`` included) raised by
    ``func`` are re-raised here with their traceback.  Called from such a
    thread already, runs ``func`` directly.  A Ctrl-C while waiting is raised
    here once the call returns control to Python (a C++ call holding the GIL
    cannot be interrupted, as on the main thread); the worker is a daemon, so
    an interrupted run does not keep the process alive.
    """
    if getattr(_local, "large", False):
        return func(*args, **kwargs)
    box: dict = {}

    def run():
        _local.large = True
        try:
            box["value"] = func(*args, **kwargs)
        except BaseException as exc:  # handed to the caller, whatever it is
            box["error"] = exc

    worker = None
    with _size_lock:
        try:
            old = threading.stack_size(STACK_BYTES)
        except (ValueError, RuntimeError):  # a platform that cannot set it: the caller's stack, as before
            pass
        else:
            try:
                worker = threading.Thread(target=run, name="lie_factors-large-stack", daemon=True)
                worker.start()
            finally:
                threading.stack_size(old)
    if worker is None:
        return func(*args, **kwargs)
    while worker.is_alive():
        worker.join(0.05)  # short joins: the main thread still sees Ctrl-C between them
    if "error" in box:
        error = box.pop("error")
        try:
            raise error
        finally:
            del error
    return box["value"]


_size_lock = threading.Lock()  # threading.stack_size is process-wide: set and restore it under a lock


def large_stack(func: Callable[..., T]) -> Callable[..., T]:
    """Decorator form of :func:`call`."""
    import functools

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        return call(func, *args, **kwargs)

    return wrapper
