"""The refit stage off the frame path: motion models fitted on a worker thread of their own.

The frame path (decode, track, flow, render) submits what the fit needs from each frame and goes on with the
newest fit that is done; it never waits for one, unless it asks to (``wait_for``, bounded). The worker fits the
newest submission only: a newer one replaces a waiting one (the slot holds one, so memory stays bounded), which
is what a stream wants when fitting is slower than the camera. NumPy and OpenCV release the GIL, so on two cores
the fit runs beside the frame path. With ``nice`` the worker thread runs at a lower OS priority than the frame
path: on a CPU too small for both (one core), frames keep their pace and the fits take the time left between
them, so they come less often instead of making every frame late. With ``duty`` below 1 the worker rests after
each fit, so that it fits at most that share of the time: on two cores, a worker fitting back to back takes the
second core that OpenCV's flow and tracking use on the frame path; resting gives it back, for older decisions.
A fit may hand over a first result before it ends (``hand_over``, from the worker's thread: a fit's clear()
waits for it to end, so a handed-over result is never one a clear() dropped).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

Observation = TypeVar("Observation")
Result = TypeVar("Result")


class BackgroundRefit(Generic[Observation, Result]):
    """Runs ``fit`` on the newest submitted observation in a daemon thread; results come back newest first.

    Attributes:
        fitted: fits done since the start.
        replaced: submissions replaced by a newer one before the worker took them.
        error: the exception of a fit that raised, without its traceback (the worker keeps running; the
            caller decides). The traceback would hold the failed fit's frames and their arrays, and a
            caller that raises the error again would tie them into a reference cycle that only a full
            garbage collection frees: the node's memory grew with every failed fit.
        niceness: the worker thread's OS niceness once it runs (None where threads cannot be reniced).
    """

    def __init__(self, fit: Callable[[Observation], Result], name: str = "moseg-refit", nice: int = 0,
                 duty: float = 1.0) -> None:
        if not 0.0 < duty <= 1.0:
            raise ValueError(f"duty must be in (0, 1], got {duty}")
        self._fit = fit
        self._nice = nice
        self._duty = duty
        self.niceness: int | None = None
        self._cond = threading.Condition()
        self._fitting = threading.Lock()  # held for each fit, so clear() never interleaves with one
        self._pending: Observation | None = None
        self._result: Result | None = None
        self._busy = False
        self._stopped = False
        self._epoch = 0  # counts clear(): a fit taken before one is dropped
        self.fitted = 0
        self.replaced = 0
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, observation: Observation) -> None:
        """Queue ``observation`` for the next fit, replacing one that still waits."""
        with self._cond:
            if self._pending is not None:
                self.replaced += 1
            self._pending = observation
            self._cond.notify_all()

    def hand_over(self, result: Result) -> None:
        """From inside ``fit``: hand ``result`` over now, as the newest (the first half of a fit whose second half
        takes long); the fit's return value replaces it when the fit ends."""
        with self._cond:
            self._result = result
            self._cond.notify_all()

    def latest(self) -> Result | None:
        """The newest finished fit (None before the first)."""
        with self._cond:
            return self._result

    def wait_for(self, accept: Callable[[Result], bool], timeout: float) -> bool:
        """Block until the newest finished fit is one that ``accept`` takes, or a fit raised, for at most
        ``timeout`` seconds; False on timeout (``latest`` and ``take_error`` then say what there is)."""
        with self._cond:
            return self._cond.wait_for(
                lambda: self.error is not None or (self._result is not None and accept(self._result)), timeout)

    def take_error(self) -> BaseException | None:
        """The error of a fit that raised since the last call, once (see ``error``: raise a new exception
        that says what it was, not this one)."""
        with self._cond:
            error, self.error = self.error, None
            return error

    def clear(self, reset: Callable[[], None] = lambda: None) -> None:
        """Drop the waiting observation and the last result, and run ``reset`` while no fit runs."""
        with self._fitting, self._cond:
            self._epoch += 1
            self._pending = None
            self._result = None
            self.error = None
            reset()

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Block until nothing waits and no fit runs; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._pending is None and not self._busy, timeout)

    def stop(self, timeout: float = 5.0) -> None:
        """End the worker after the fit it runs, if any."""
        with self._cond:
            self._stopped = True
            self._cond.notify_all()
        self._thread.join(timeout)

    def _lower_priority(self) -> None:
        """Add ``nice`` to this thread's niceness (Linux: a thread is a task with a priority of its own)."""
        try:
            me = threading.get_native_id()
            if self._nice > 0:
                os.setpriority(os.PRIO_PROCESS, me, min(os.getpriority(os.PRIO_PROCESS, me) + self._nice, 19))
            self.niceness = os.getpriority(os.PRIO_PROCESS, me)
        except (AttributeError, OSError):  # no per-thread priorities on this OS: the fit keeps the frame path's
            self.niceness = None

    def _run(self) -> None:
        self._lower_priority()
        rest = 0.0
        while True:
            with self._cond:
                # The rest after a fit (``duty``) ends early when the worker is stopped.
                if rest > 0 and self._cond.wait_for(lambda: self._stopped, rest):
                    return
                self._cond.wait_for(lambda: self._pending is not None or self._stopped)
                if self._stopped:
                    return
                observation, self._pending = self._pending, None
                self._busy, epoch = True, self._epoch
            with self._fitting:
                fresh = epoch == self._epoch
                start = time.perf_counter()
                try:
                    result, error = (self._fit(observation) if fresh else None), None
                except Exception as caught:  # handed to the frame path, which turns it into a frame status
                    result, error = None, caught
                seconds = time.perf_counter() - start
                rest = seconds * (1.0 / self._duty - 1.0)
                with self._cond:  # still under _fitting: a clear() cannot slip in between fit and hand-over
                    self._busy = False
                    if fresh:
                        if error is None:
                            self._result = result
                            self.fitted += 1
                        else:
                            self.error = error.with_traceback(None)
                    self._cond.notify_all()


class RefitError(RuntimeError):
    """A background refit raised; the message names the original exception and its text."""

    @classmethod
    def of(cls, error: BaseException) -> RefitError:
        """The RefitError that reports ``error``."""
        return cls(f"{type(error).__name__}: {error}")


def raise_worker_error(worker: BackgroundRefit) -> None:
    """Raise a RefitError for the error of a fit of ``worker`` that raised since the last call, if any."""
    error = worker.take_error()
    if error is not None:
        raise RefitError.of(error)
