"""panorecon/io/process.py: the memory budget a stage that knows its need checks against."""

import sys

import pytest

from panorecon.io import memory_budget_mb
from panorecon.io.process import MEMORY_BUDGET_ENV


def test_the_budget_is_the_environment_variable_when_set(monkeypatch):
    monkeypatch.setenv(MEMORY_BUDGET_ENV, "1234.5")
    assert memory_budget_mb() == 1234.5


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="MemAvailable is Linux's /proc/meminfo")
def test_without_it_the_budget_is_the_memory_available(monkeypatch):
    monkeypatch.delenv(MEMORY_BUDGET_ENV, raising=False)
    with open("/proc/meminfo") as f:
        total = next(int(line.split()[1]) for line in f if line.startswith("MemTotal:")) / 1024
    assert 0 < memory_budget_mb() <= total


@pytest.mark.parametrize("value", ["lots", "-5", "nan", "0"])
def test_a_budget_that_is_no_positive_number_is_one_clear_error(monkeypatch, value):
    from panorecon.io import PanoreconInputError

    monkeypatch.setenv(MEMORY_BUDGET_ENV, value)
    with pytest.raises(PanoreconInputError, match=MEMORY_BUDGET_ENV):
        memory_budget_mb()
