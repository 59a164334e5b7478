"""A training run's signals: SIGTERM (what SLURM sends before a time limit) and Ctrl-C stop it after
its current step, with a checkpoint, and a step stuck in compiled code is not waited for past a
grace time."""

from __future__ import annotations

import os
import select
import signal
import socket
import sys
import threading
import time
from contextlib import contextmanager


_ending = threading.Lock()  # held by whichever of the handler and the watchdog ends the process


def _end_now(code: int, message: str) -> None:
    """End the process at once with `code`, saying `message` (once: the handler and the watchdog
    both see a second Ctrl-C); no traceback, no exit handlers: the run resumes from its last
    checkpoint."""
    _ending.acquire()  # never released: the other caller waits here until the process has ended
    sys.stderr.write(message + "\n")
    sys.stderr.flush()
    os._exit(code)


@contextmanager
def stop_on_signals(grace: float = 60.0):
    """SIGTERM (what SLURM sends before a time limit) and a first Ctrl-C ask a training run to stop
    after its current step, checkpointed; a Ctrl-C after that ends it at once (exit 130, one line,
    no traceback).  A step that does not finish within `grace` seconds of the signal is not waited
    for: the run stops there, keeping what it had checkpointed (a scheduler's preemption is never
    ignored).  Yields a callable: the signal asked for, or 0."""
    asked: list[int] = []
    # handlers live in the main thread
    if threading.current_thread() is not threading.main_thread():
        yield lambda: 0
        return

    def handler(signum, frame):
        if asked and signum == signal.SIGINT:
            _end_now(128 + signum, AGAIN)
        asked.append(signum)
        sys.stderr.write(
            f"{signal.Signals(signum).name}: stopping after the current step, with a checkpoint"
            + (" (Ctrl-C again to interrupt at once)" if signum == signal.SIGINT else "")
            + "\n"
        )

    old = {s: signal.signal(s, handler) for s in (signal.SIGTERM, signal.SIGINT)}
    # Python runs `handler` only when the main thread is back in the interpreter, which a step stuck
    # in compiled code never is; the signal's byte on the wakeup fd reaches the watchdog thread at
    # once.
    receive, send = socket.socketpair()
    send.setblocking(False)
    old_fd = signal.set_wakeup_fd(send.fileno(), warn_on_full_buffer=False)
    left = threading.Event()  # the run has left stop_on_signals: its own exit handling takes over
    threading.Thread(
        target=_stop_within, args=(receive, grace, left), daemon=True, name="nma-stop-within"
    ).start()
    try:
        yield lambda: asked[0] if asked else 0
    finally:
        left.set()
        signal.set_wakeup_fd(old_fd)
        send.close()  # the watchdog reads the end of it and returns
        for s, h in old.items():
            signal.signal(s, h)


AGAIN = "SIGINT: stopping now; the run resumes from its last checkpoint"


def _stop_within(receive: socket.socket, grace: float, left: threading.Event) -> None:
    """The watchdog of stop_on_signals: `grace` seconds after the first SIGTERM or SIGINT, ends the
    process with 128 + that signal unless it has ended by itself; a Ctrl-C after the first signal
    ends it at once."""
    first: tuple[int, float] | None = None
    with receive:
        while True:
            timeout = None if first is None else max(0.0, first[1] + grace - time.monotonic())
            if not select.select([receive], [], [], timeout)[0]:
                name = signal.Signals(first[0]).name
                _end_now(
                    128 + first[0],
                    f"{name}: the current step did not finish within "
                    f"trainer.stop_grace = {grace:g} s; stopping now: the run "
                    "resumes from its last checkpoint",
                )
            data = receive.recv(64)
            if not data or left.is_set():
                return  # the run left stop_on_signals
            signals = [n for n in data if n in (signal.SIGTERM, signal.SIGINT)]
            if signals and first is None:
                first, signals = (signals[0], time.monotonic()), signals[1:]
            if signal.SIGINT in signals:  # a Ctrl-C after the first, even during compiled code
                _end_now(128 + signal.SIGINT, AGAIN)
