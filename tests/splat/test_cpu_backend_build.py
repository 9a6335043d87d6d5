"""Loading the C++ backend: a build interrupted by a killed process must not make every later load wait forever
on the lock file torch leaves behind; a failed build says why; the sources build under the C++ standard that
older torch releases compile extensions with."""

import os
import shutil
import subprocess
import sys
import sysconfig
import textwrap
import threading
from concurrent.futures import ThreadPoolExecutor

import pytest
import torch.utils.cpp_extension

from panorecon.splat.rasterize import cpu_backend, resolve_backend


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


def test_torch_builds_with_the_ninja_package_whatever_ninja_path_finds_first(tmp_path, monkeypatch):
    """Two ninja versions discard each other's build log, and then every object is rebuilt: the build runs with
    the ``ninja`` package's binary first on PATH, and PATH is as it was afterwards."""
    ninja = pytest.importorskip("ninja")
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path))
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    monkeypatch.setattr(cpu_backend, "_module", None)
    monkeypatch.setattr(cpu_backend, "_error", None)
    seen = {}

    def fake_load(name, sources, build_directory, **kwargs):
        seen["ninja"] = shutil.which("ninja")
        return "module"

    monkeypatch.setattr(torch.utils.cpp_extension, "load", fake_load)
    assert cpu_backend.load() == "module"
    assert seen["ninja"] == shutil.which("ninja", path=ninja.BIN_DIR)
    assert os.environ["PATH"] == "/usr/bin:/bin"


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


NINJA_FAILURE = (
    "Error building extension 'panorecon_rasterize_cpu': [1/2] /opt/gcc/bin/g++ -MMD -MF project_cpu.o.d -c "
    "project_cpu.cpp -o project_cpu.o\nFAILED: project_cpu.o\n/work/csrc/project_cpu.cpp:41:33: error: "
    "'remove_cvref_t' in namespace 'std' does not name a template type\nninja: build stopped: subcommand failed.\n"
)


def test_a_failed_build_names_the_compilers_first_error(tmp_path, monkeypatch, caplog):
    """The reason logged and raised is the compiler's first error (file, line, what), not ninja's command line."""
    monkeypatch.setenv("PANORECON_CACHE", str(tmp_path))
    monkeypatch.setattr(cpu_backend, "_module", None)
    monkeypatch.setattr(cpu_backend, "_error", None)

    def failing_load(name, sources, build_directory, **kwargs):
        raise RuntimeError(NINJA_FAILURE)

    monkeypatch.setattr(torch.utils.cpp_extension, "load", failing_load)
    with caplog.at_level("WARNING", logger="panorecon.splat"):
        assert cpu_backend.load() is None
    reason = cpu_backend.unavailable_reason()
    assert reason == (
        "RuntimeError: Error building extension 'panorecon_rasterize_cpu'; /work/csrc/project_cpu.cpp:41:33: "
        "error: 'remove_cvref_t' in namespace 'std' does not name a template type"
    )
    assert reason in caplog.text and "-MMD" not in caplog.text
    with pytest.raises(RuntimeError, match="project_cpu.cpp:41:33: error"):
        resolve_backend("cpu")
    with pytest.raises(RuntimeError, match="CUDA tensors"):  # the device mismatch is said first, built or not
        resolve_backend("cpu", cuda_tensors=True)


def test_a_missing_compiler_is_named():
    failure = RuntimeError(
        "Error building extension 'x': [1/2] /nonexistent/g++ -c module.cpp -o module.o\nFAILED: module.o\n"
        "/nonexistent/g++ -c module.cpp -o module.o\n/bin/sh: 1: /nonexistent/g++: not found\n"
        "ninja: build stopped: subcommand failed.\n"
    )
    assert cpu_backend.build_failure(failure) == (
        "RuntimeError: Error building extension 'x'; /bin/sh: 1: /nonexistent/g++: not found"
    )


def test_the_sources_parse_as_cxx17(tmp_path):
    """torch's cpp_extension compiles with -std=c++17 up to torch 2.11 (c++20 from later releases): a C++20-only
    name in csrc/ (std::remove_cvref_t, found on a GPU machine with torch 2.11 and GCC 13) breaks the build there
    while it passes here. Each source is parsed as C++17 against this torch's headers."""
    compiler = os.environ.get("CXX", "c++")
    if shutil.which(compiler) is None:
        pytest.skip(f"no C++ compiler {compiler!r}")
    includes = [f"-isystem{p}" for p in torch.utils.cpp_extension.include_paths()]
    includes.append(f"-isystem{sysconfig.get_paths()['include']}")
    flags = ["-std=c++17", "-fsyntax-only", "-DTORCH_EXTENSION_NAME=x", "-DTORCH_API_INCLUDE_EXTENSION_H"]
    flags += [f for f in cpu_backend.CFLAGS if not f.startswith("-O")]

    def parse(source):
        return subprocess.run([compiler, *flags, *includes, str(source)], capture_output=True, text=True)

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        results = dict(zip(cpu_backend._SOURCES, pool.map(parse, cpu_backend._SOURCES)))
    failed = {s.name: r.stderr.splitlines()[:3] for s, r in results.items() if r.returncode != 0}
    assert not failed, failed
