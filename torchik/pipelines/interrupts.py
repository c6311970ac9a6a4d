"""Work that Ctrl-C must not cut in half: a part of a run handed to every output."""

from __future__ import annotations

import signal
from contextlib import contextmanager
from typing import Any, Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Hold SIGINT and SIGTERM while the block runs, then act on them as their handlers would have
    (KeyboardInterrupt, or the command line's Terminated): a part written to some outputs and not to
    others would leave them disagreeing. Off the main thread, where Python takes no signals, the
    block just runs."""
    received: list[int] = []
    previous: dict[int, Any] = {}  # the handlers replaced
    try:
        for signum in SIGNALS:
            handler = signal.getsignal(signum)
            if handler not in (signal.SIG_IGN, None):
                previous[signum] = signal.signal(signum, lambda number, _: received.append(number))
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        for number in dict.fromkeys(received):
            if callable(previous[number]):
                previous[number](number, None)
            else:  # SIG_DFL: the default action, now that it is back
                signal.raise_signal(number)
