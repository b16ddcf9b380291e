"""Guards of a training process: one writer per run directory, and signals that stop cleanly.

* :func:`lock_run` takes an exclusive ``flock`` on ``RUN_DIR/.lock`` for the life of the
  training; the kernel releases it when the process dies (even by SIGKILL), so a stale lock never
  blocks a resume, while a second live ``train`` on the same directory is refused.
* :class:`StopSignals` turns SIGINT and SIGTERM into a request the training loop reads between
  chunks: the loop finishes the chunk it is in, checkpoints, and exits with 130 (SIGINT) or
  143 (SIGTERM). A second signal exits at once with the same status; checkpoints are written to a
  temporary directory and renamed, so the last complete one is never damaged.
  Before the loop begins (building, restoring, compiling) a signal ends the command at once:
  everything written by then is written atomically, and a resume goes on as after SIGKILL.
* :func:`interruptible` runs a long call into XLA (a compilation, a jitted init) in a worker
  thread while the main thread waits for it, so that such a signal is handled within a fraction
  of a second instead of after a compile of seconds to minutes that holds the main thread in C++.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any, TypeVar

T = TypeVar("T")


# The file descriptor that reaches the user's stderr while fd 2 is captured (``checkpoint``'s
# filter of orbax's native tracebacks): a signal's last line must not vanish into a capture.
_REAL_STDERR: list[int] = []


def say(text: str) -> None:
    """Writes ``text`` to the user's stderr at once, also while fd 2 is being captured."""
    sys.stdout.flush()
    sys.stderr.flush()
    os.write(_REAL_STDERR[-1] if _REAL_STDERR else 2, text.encode())


@contextlib.contextmanager
def real_stderr(fd: int) -> Iterator[None]:
    """While fd 2 is captured, ``say`` writes to ``fd`` (the saved original)."""
    _REAL_STDERR.append(fd)
    try:
        yield
    finally:
        _REAL_STDERR.remove(fd)


class RunLockedError(Exception):
    """Another live process holds the run directory."""


@contextlib.contextmanager
def lock_run(run_dir: str, name: str = ".lock") -> Iterator[None]:
    """Holds ``RUN_DIR/<name>`` exclusively; raises RunLockedError when another process has it.
    (Each process of a multi-process population locks a name of its own.) A directory this call
    made is removed again when the lock is all it holds at the end (a start that failed before
    writing anything leaves no folder behind)."""
    made = not os.path.isdir(run_dir)
    os.makedirs(run_dir, exist_ok=True)
    path = os.path.join(run_dir, name)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "unknown"
            raise RunLockedError(
                f"{run_dir} is being trained by another process (pid {holder}); wait for it or "
                "stop it first"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
    finally:
        if made and os.listdir(run_dir) == [name]:
            os.unlink(path)
            os.rmdir(run_dir)
        os.close(fd)  # closing releases the lock


EXIT_STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}


def _install(handler: Callable, signums: tuple[int, ...]) -> dict[int, object]:
    """Installs ``handler`` for ``signums`` (only the main thread can); returns the previous
    handlers, empty where nothing was installed."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {signum: signal.signal(signum, handler) for signum in signums}


def _restore(previous: dict[int, object]) -> None:
    for signum, handler in previous.items():
        signal.signal(signum, handler)


class TerminatedError(Exception):
    """SIGTERM arrived outside training's own handler (see ``sigterm_raises``)."""


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """SIGTERM raises TerminatedError, as Python makes SIGINT raise KeyboardInterrupt, so a
    command stopped outside training exits with one line and 143 instead of silently."""

    def handler(signum: int, frame: FrameType | None) -> None:
        raise TerminatedError

    previous = _install(handler, (signal.SIGTERM,))
    try:
        yield
    finally:
        _restore(previous)


@contextlib.contextmanager
def exit_on_signals() -> Iterator[None]:
    """SIGINT/SIGTERM end the process at once with one line ("minatt-jax: interrupted" /
    "terminated") and exit status 130 / 143: for the console command, whose files are all
    written atomically. An exception raised from a handler instead can land inside a callback
    that swallows it (XLA's gc callback) or unwind through compilation; exiting from the handler
    cannot. Training installs its own ``StopSignals`` inside, which stop after a chunk."""
    words = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated"}

    def handler(signum: int, frame: FrameType | None) -> None:
        del frame
        say(f"minatt-jax: {words.get(signum, 'stopped')}\n")
        os._exit(EXIT_STATUS.get(signum, 1))

    previous = _install(handler, (signal.SIGINT, signal.SIGTERM))
    try:
        yield
    finally:
        _restore(previous)


class StopSignals:
    """Context manager: records the first SIGINT/SIGTERM in ``received``; a second one exits.
    Until ``training()`` (the run loop has begun) and while ``interruptible`` work runs, the first
    one exits at once, saying how to resume (``resume_hint``).

    Only installs handlers in the main thread (Python delivers signals there); elsewhere it is
    inert and signals keep their defaults.
    """

    def __init__(self, resume_hint: str = "") -> None:
        self.received: int | None = None
        self.resume_hint = resume_hint
        self.phase: str | None = "starting"  # None: the run loop, which stops between chunks
        self._previous: dict[int, object] = {}

    @property
    def exit_status(self) -> int:
        return EXIT_STATUS.get(self.received, 1) if self.received is not None else 0

    def training(self) -> None:
        """The run loop begins: a signal now stops after the chunk in progress."""
        self.phase = None

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        del frame
        name = signal.Signals(signum).name
        if self.phase is not None:
            self.exit_at_once(signum)
        if self.received is not None:
            say(f"\nminatt-jax: second {name}: exiting now; the last complete checkpoint is "
                "kept\n")  # fmt: skip
            os._exit(EXIT_STATUS.get(signum, 1))
        self.received = signum
        say(f"\nminatt-jax: {name} received: stopping after the current chunk (send it again "
            "to exit at once)\n")  # fmt: skip

    def exit_at_once(self, signum: int) -> None:
        """Ends the process now (outside the run loop nothing is half-written)."""
        hint = f"; resume with: {self.resume_hint}" if self.resume_hint else ""
        say(f"\nminatt-jax: stopped by {signal.Signals(signum).name} while {self.phase}: no "
            f"step is lost{hint}\n")  # fmt: skip
        os._exit(EXIT_STATUS.get(signum, 1))

    def __enter__(self) -> StopSignals:
        self._previous = _install(self._handle, tuple(EXIT_STATUS))
        if self._previous:
            _ACTIVE.append(self)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._previous:
            _ACTIVE.remove(self)
        _restore(self._previous)


_ACTIVE: list[StopSignals] = []


def interruptible(work: Callable[[], T], phase: str = "compiling") -> T:
    """``work()``, run in a worker thread while the main thread waits in short joins, so that a
    signal under an active ``StopSignals`` ends the command at once (its handler runs between
    the joins). Without one, or off the main thread, simply ``work()``."""
    if not _ACTIVE or threading.current_thread() is not threading.main_thread():
        return work()
    stop = _ACTIVE[-1]
    previous, stop.phase = stop.phase, phase
    if stop.received is not None:  # came before: the work would only delay the stop
        stop.exit_at_once(stop.received)
    box: dict[str, Any] = {}

    def run() -> None:
        try:
            box["value"] = work()
        except BaseException as e:  # noqa: BLE001 - handed to the main thread as it is
            box["error"] = e

    worker = threading.Thread(target=run, name=f"minatt-jax {phase}", daemon=True)
    try:
        worker.start()
        while worker.is_alive():
            worker.join(0.05)
    finally:
        stop.phase = previous
    if "error" in box:
        raise box["error"]
    return box["value"]
