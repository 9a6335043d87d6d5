"""What a process has used so far, for the time-and-memory columns every report carries."""

from __future__ import annotations

import math
import resource


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MB; Linux reports ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def reset_peak_rss() -> bool:
    """Start a new peak-memory window for ``window_peak_rss_mb`` (Linux: ``5`` written to /proc/self/clear_refs
    resets VmHWM to the current RSS); False where the system does not allow it (the window then is the process's
    life so far)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def window_peak_rss_mb() -> float:
    """Peak resident memory (MB) since the last ``reset_peak_rss`` (VmHWM of /proc/self/status); without /proc,
    the process's peak so far (``peak_rss_mb``)."""
    peak = _proc_mb("/proc/self/status", "VmHWM")
    return peak_rss_mb() if peak is None else peak


def _proc_mb(path: str, key: str) -> float | None:
    """The ``key:`` line of a /proc file that counts in kB (VmHWM, MemAvailable), in MB; None where unreadable."""
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


MEMORY_BUDGET_ENV = "PANORECON_MEMORY_BUDGET_MB"


def memory_budget_mb() -> float | None:
    """The memory (MB) a stage that knows its own need may still take: ``$PANORECON_MEMORY_BUDGET_MB`` when set,
    else the system's MemAvailable (/proc/meminfo, the memory other processes leave, as the kernel estimates it);
    None where neither is known."""
    import os

    env = os.environ.get(MEMORY_BUDGET_ENV)
    if env:
        try:
            budget = float(env)
        except ValueError:
            budget = math.nan
        if not (math.isfinite(budget) and budget > 0):
            from .files import PanoreconInputError

            raise PanoreconInputError(f"${MEMORY_BUDGET_ENV}={env!r}: expected a positive number of MB")
        return budget
    return _proc_mb("/proc/meminfo", "MemAvailable")
