"""The ``firmtool`` node's goal queries, answered off the control loop (no ROS import).

Written here rather than with ``concurrent.futures.ThreadPoolExecutor`` because an executor's thread
is joined when the interpreter exits: a node stopped while a query ran (minutes on a loaded machine)
did not end until the query did.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any


class QueryWorker:
    """One daemon thread answering goals' queries one at a time, newest first: a goal waiting while an
    older one is answered replaces any goal waiting before it (whose future is cancelled). A daemon, so
    that a node stopped (Ctrl-C, SIGTERM) while a query runs ends at once rather than after it."""

    def __init__(self) -> None:
        self._cv = threading.Condition()
        self._waiting: tuple[Future, Callable, tuple] | None = None
        self._closed = False
        threading.Thread(target=self._run, name="firmtool-query", daemon=True).start()

    def submit(self, fn: Callable, *args: Any) -> Future:
        future: Future = Future()
        with self._cv:
            if self._waiting is not None:
                self._waiting[0].cancel()
            self._waiting = (future, fn, args)
            self._cv.notify()
        return future

    def _run(self) -> None:
        while True:
            with self._cv:
                while self._waiting is None and not self._closed:
                    self._cv.wait()
                if self._closed:
                    return
                future, fn, args = self._waiting
                self._waiting = None
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn(*args))
            except BaseException as exc:  # noqa: BLE001 - handed to the main thread, which refuses the goal
                future.set_exception(exc)

    def close(self) -> None:
        with self._cv:
            self._closed = True
            if self._waiting is not None:
                self._waiting[0].cancel()
            self._cv.notify()


__all__ = ["QueryWorker"]
