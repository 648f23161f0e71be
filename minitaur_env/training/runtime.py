"""The process around a run: Ctrl-C and SIGTERM as exceptions, and torch's thread count."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from typing import Any


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Python was when it arrived, so it unwinds like Ctrl-C."""


@contextlib.contextmanager
def stop_signals_as_exceptions() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` and SIGINT KeyboardInterrupt.

    SIGINT is set explicitly because a process started in the background by a
    non-interactive shell (``train.py &`` in a script, some CI runners) inherits it
    ignored, and Python then installs no KeyboardInterrupt handler: ``kill -INT`` would
    do nothing instead of checkpointing. Main thread only, where handlers can be set.
    """
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return

    def handler(signum: int, frame: Any) -> None:
        raise Terminated(signum)

    previous = {
        signal.SIGTERM: signal.signal(signal.SIGTERM, handler),
        signal.SIGINT: signal.signal(signal.SIGINT, signal.default_int_handler),
    }
    try:
        yield
    finally:
        for sig, earlier in previous.items():
            signal.signal(sig, earlier)


def signal_of(error: KeyboardInterrupt) -> int:
    return signal.SIGTERM if isinstance(error, Terminated) else signal.SIGINT


@contextlib.contextmanager
def ignoring_more_signals() -> Iterator[None]:
    """While the interrupt checkpoint is written, a second Ctrl-C/SIGTERM must not tear it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def set_torch_threads(num_threads: int, policy: str) -> None:
    """``num_threads`` torch threads; 0: one, unless the policy is a CNN.

    A few-layer MLP gains little from more threads on an idle machine (SAC: 67.6 env
    steps/s with one, 86.6 with two), and loses everything on a busy one: torch's threads
    spin-wait against any other process on their cores (a 1,200-step SAC run took 400 s
    beside a training run, 30 s with one thread). ``benchmarks/threads_under_load.py``
    measures both.
    """
    import torch

    if num_threads > 0:
        torch.set_num_threads(num_threads)
    elif "cnn" not in str(policy).lower():
        torch.set_num_threads(1)
