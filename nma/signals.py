"""A training run's signals: SIGTERM (what SLURM sends before a time limit) and Ctrl-C stop it after its
current step, with a checkpoint, and a step stuck in compiled code is not waited for past a grace time."""
from __future__ import annotations

import os
import select
import signal
import socket
import sys
import threading
import time
from contextlib import contextmanager


@contextmanager
def stop_on_signals(grace: float = 60.0):
    """SIGTERM (what SLURM sends before a time limit) and a first Ctrl-C ask a training run to stop after
    its current step, checkpointed; a second Ctrl-C interrupts at once.  A step that does not finish
    within `grace` seconds of the signal is not waited for: the run stops there, keeping what it had
    checkpointed (a scheduler's preemption is never ignored).  Yields a callable: the signal asked for,
    or 0."""
    asked: list[int] = []
    if threading.current_thread() is not threading.main_thread():  # handlers live in the main thread
        yield lambda: 0
        return

    def handler(signum, frame):
        asked.append(signum)
        if signum == signal.SIGINT:
            signal.signal(signal.SIGINT, signal.default_int_handler)
        sys.stderr.write(f"{signal.Signals(signum).name}: stopping after the current step, with a checkpoint"
                         + (" (Ctrl-C again to interrupt at once)" if signum == signal.SIGINT else "") + "\n")

    old = {s: signal.signal(s, handler) for s in (signal.SIGTERM, signal.SIGINT)}
    # Python runs `handler` only when the main thread is back in the interpreter, which a step stuck in
    # compiled code never is; the signal's byte on the wakeup fd reaches the watchdog thread at once.
    receive, send = socket.socketpair()
    send.setblocking(False)
    old_fd = signal.set_wakeup_fd(send.fileno(), warn_on_full_buffer=False)
    threading.Thread(target=_stop_within, args=(receive, grace), daemon=True, name="nma-stop-within").start()
    try:
        yield lambda: asked[0] if asked else 0
    finally:
        signal.set_wakeup_fd(old_fd)
        send.close()  # the watchdog reads the end of it and returns
        for s, h in old.items():
            signal.signal(s, h)


def _stop_within(receive: socket.socket, grace: float) -> None:
    """The watchdog of stop_on_signals: `grace` seconds after the first SIGTERM or SIGINT, ends the
    process with 128 + that signal unless it has ended by itself."""
    first: tuple[int, float] | None = None
    with receive:
        while True:
            timeout = None if first is None else max(0.0, first[1] + grace - time.monotonic())
            if not select.select([receive], [], [], timeout)[0]:
                name = signal.Signals(first[0]).name
                sys.stderr.write(f"{name}: the current step did not finish within trainer.stop_grace = {grace:g} s; "
                                 f"stopping now: the run resumes from its last checkpoint\n")
                sys.stderr.flush()
                os._exit(128 + first[0])
            data = receive.recv(64)
            if not data:
                return  # the run left stop_on_signals
            signals = [n for n in data if n in (signal.SIGTERM, signal.SIGINT)]
            if signals and first is None:
                first = (signals[0], time.monotonic())
