"""Ctrl-C (SIGINT) and SIGTERM as one clean exit.

``cli.main`` calls ``install()``: SIGTERM then raises ``Interrupted`` like SIGINT raises KeyboardInterrupt
(``Interrupted`` is one), so every ``atomic_write`` in flight deletes its temp file and nothing is half-written.
Inside ``at_step_boundaries`` (the trainer's step loop) a signal only sets a flag: at the next step boundary
the loop writes its checkpoint and raises ``Interrupted`` with the step and the checkpoint's path. main
prints ``Interrupted.line()`` and exits 128 + the signal number (130 for SIGINT, 143 for SIGTERM).
Inside ``held`` (creating a temp file; renaming a command's finished outputs into place) a signal waits for
the block's end. Once a
command has returned, ``end_at_exit`` makes a signal during the interpreter's exit (atexit callbacks such as
torch's library finalizers) end the process at once with one line instead of an ignored-exception traceback.
"""

from __future__ import annotations

import atexit
import os
import signal
import sys
from collections.abc import Callable, Iterable, Iterator

from .io.signals import SIGNALS, _main_thread, held  # noqa: F401  (held: re-exported for callers)

_pending: list[int] = []


class Interrupted(KeyboardInterrupt):
    """A SIGINT/SIGTERM, with what was saved (``where``: e.g. 'at step 40 of 300; checkpoint at RUN/ckpt.pt')."""

    def __init__(self, signum: int = signal.SIGINT, where: str | None = None):
        super().__init__(signum, where)
        self.signum, self.where = signum, where

    @property
    def exit_code(self) -> int:
        return 128 + int(self.signum)

    def line(self) -> str:
        name = signal.Signals(self.signum).name
        if self.where and "checkpoint at" in self.where:
            return f"panorecon: interrupted by {name} {self.where}; rerun the same command to resume"
        where = f" {self.where}" if self.where else ""
        return (
            f"panorecon: interrupted by {name}{where}; no output was half-written (each is written whole or not "
            "at all); rerun the same command"
        )


def _raise(signum, frame):
    raise Interrupted(signum)


def _defer(signum, frame):
    _pending.append(signum)


def install() -> None:
    """SIGINT and SIGTERM raise ``Interrupted`` (main thread only; elsewhere nothing changes)."""
    if _main_thread():
        for s in SIGNALS:
            signal.signal(s, _raise)


def at_step_boundaries(steps: Iterable[int], total: int, checkpoint: Callable[[int], str]) -> Iterator[int]:
    """Yield ``steps`` (step indices); a SIGINT/SIGTERM received meanwhile is only recorded, and before the next
    step is yielded ``checkpoint(step)`` (when at least one step is done) writes the state and ``Interrupted``
    is raised naming the step and the path it returned. The previous handlers come back when the loop ends."""
    if not _main_thread():
        yield from steps
        return
    old = {s: signal.getsignal(s) for s in SIGNALS}
    _pending.clear()
    for s in SIGNALS:
        signal.signal(s, _defer)
    try:
        for step in steps:
            if _pending:
                signum = _pending[0]
                _pending.clear()
                saved = f"; checkpoint at {checkpoint(step)}" if step > 0 else " (no step done, no checkpoint)"
                raise Interrupted(signum, f"at step {step} of {total}{saved}")
            yield step
        if _pending:  # arrived during the last step: acted on now, as the old handler would have
            raise Interrupted(_pending[0])
    finally:
        _pending.clear()
        for s, h in old.items():
            signal.signal(s, h)


def _end_now(signum, frame):
    """A signal while the interpreter exits: the command had finished, so say so and end now (os._exit skips the
    remaining atexit callbacks, one of which may be what hangs)."""
    name = signal.Signals(signum).name
    sys.stdout.flush()
    print(f"panorecon: {name} while exiting, after the command had finished; its outputs are whole", file=sys.stderr)
    sys.stderr.flush()
    os._exit(128 + int(signum))


def _install_end_now() -> None:
    if _main_thread():
        for s in SIGNALS:
            signal.signal(s, _end_now)


def end_at_exit() -> None:
    """From the interpreter's exit on, SIGINT/SIGTERM end the process at once with one line and 128 + the signal
    number. Registered (again) after each command, so it runs before the atexit callbacks registered earlier
    (atexit runs the last registered first; weakref.finalize's, which runs torch's library finalizers, is
    registered when torch is first imported)."""
    atexit.unregister(_install_end_now)
    atexit.register(_install_end_now)
