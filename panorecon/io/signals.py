"""SIGINT/SIGTERM held off around a block that must not stop halfway (``atomic_write`` creating its temp file,
``atomic_write_all`` renaming a command's outputs into place). Standard library only: ``io`` imports nothing of
panorecon's; ``panorecon.interrupts`` builds the commands' interrupt handling on it."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def held() -> Iterator[None]:
    """Run a short block that must not stop halfway (creating a temp file and noting its name; renaming finished
    outputs into place) with SIGINT and SIGTERM only recorded; when the block has ended the previous handlers
    come back and the first signal received is raised again (``signal.raise_signal``), so they act on it as if
    it had just arrived. Main thread only, with Python-set handlers; elsewhere nothing changes."""
    old = {s: signal.getsignal(s) for s in SIGNALS} if _main_thread() else {}
    if not old or None in old.values():  # None: a handler set outside Python, which could not be put back
        yield
        return
    received: list[int] = []
    for s in SIGNALS:
        signal.signal(s, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if received:
            signal.raise_signal(received[0])
