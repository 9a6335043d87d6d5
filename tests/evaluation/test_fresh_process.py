"""``in_fresh_process``: a result comes back, and a child's exception is raised in the parent (it used to hang)."""

import os

import pytest

from panorecon.evaluation.environment import in_fresh_process


def test_an_exception_in_the_child_is_raised_not_waited_for():
    with pytest.raises(FileNotFoundError):
        in_fresh_process(os.path.getsize, "/nonexistent/panorecon")


def test_a_child_killed_without_answering_raises():
    with pytest.raises(RuntimeError, match="exit code"):
        in_fresh_process(os._exit, 3)


def test_a_result_comes_back_with_its_peak_rss():
    out = in_fresh_process(dict, [("a", 1)])
    assert out["a"] == 1 and out["peak_rss_mb"] > 0
