"""Loading the C++ backend: a build interrupted by a killed process must not make every later load wait forever
on the lock file torch leaves behind."""

import subprocess
import sys
import textwrap
import threading

import torch.utils.cpp_extension

from panorecon.splat.rasterize import cpu_backend


def test_a_lock_left_by_a_killed_build_is_removed_before_building(tmp_path, monkeypatch):
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path))
    monkeypatch.setattr(cpu_backend, "_module", None)
    monkeypatch.setattr(cpu_backend, "_error", None)
    stale = cpu_backend.build_dir() / "lock"
    stale.touch()  # what torch's FileBaton leaves when its process is killed mid-build
    seen = {}

    def fake_load(name, sources, build_directory, **kwargs):
        seen["lock_present"] = stale.exists()
        seen["directory"] = build_directory
        return "module"

    monkeypatch.setattr(torch.utils.cpp_extension, "load", fake_load)
    assert cpu_backend.load() == "module"
    assert seen == {"lock_present": False, "directory": str(stale.parent)}


def test_a_build_in_progress_in_another_process_is_waited_for_not_broken(tmp_path, monkeypatch):
    """While another live process holds the build lock, its torch ``lock`` file is left alone: load waits."""
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path))
    directory = cpu_backend.build_dir()
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(f"""
        import fcntl, pathlib, sys
        d = pathlib.Path({str(directory)!r})
        h = open(d / "build.flock", "w"); fcntl.flock(h, fcntl.LOCK_EX)
        (d / "lock").touch(); print("holding", flush=True)
        sys.stdin.readline()            # build 'runs' until the test says stop
        (d / "lock").unlink(); fcntl.flock(h, fcntl.LOCK_UN)
        """),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "holding"
        monkeypatch.setattr(cpu_backend, "_module", None)
        monkeypatch.setattr(cpu_backend, "_error", None)
        order = []

        def fake_load(name, sources, build_directory, **kwargs):
            order.append("load")
            return "module"

        monkeypatch.setattr(torch.utils.cpp_extension, "load", fake_load)
        loader = threading.Thread(target=lambda: order.append(cpu_backend.load()))
        loader.start()
        loader.join(timeout=1.0)
        assert loader.is_alive() and order == [] and (directory / "lock").exists()
        order.append("released")
        holder.stdin.write("\n")
        holder.stdin.flush()
        loader.join(timeout=30)
        assert order == ["released", "load", "module"]
    finally:
        holder.kill()
        holder.wait()


def test_each_checkout_builds_in_its_own_directory(tmp_path, monkeypatch):
    """Two checkouts sharing one cache must not rebuild over each other's sources on every load."""
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path))
    here = cpu_backend.build_dir()
    other = [tmp_path / "other_checkout" / "csrc" / p.name for p in cpu_backend._SOURCES]
    monkeypatch.setattr(cpu_backend, "_SOURCES", other)
    there = cpu_backend.build_dir()
    assert here != there and here.parent == there.parent == tmp_path / "torch_extensions"
