"""What the user-wide cache builds once (the FMU runtimes, the Windows Python) is built once when several processes
ask at the same time, as two test workers or a sweep's workers do on a fresh machine: one builds, the others wait
and find it built. Before, the second Windows Python failed to move into place ("Directory not empty"). An FMU and
the C host are built once per content and copied after that."""

import logging
import os
import shutil
import subprocess
import threading
import time
from pathlib import Path

import pytest

import nfal
from nfal.apps import host_check
from nfal.fmus import build, export_runtime, windows_python
from nfal.cache_folder import exclusive, write_in_one_step


def _at_once(function, count=3):
    """``function()`` in ``count`` threads started together: their results, in order (an exception is re-raised)."""
    results, barrier = [None] * count, threading.Barrier(count)

    def run(i):
        barrier.wait()
        try:
            results[i] = function()
        except Exception as exc:  # noqa: BLE001 - handed to the test
            results[i] = exc

    threads = [threading.Thread(target=run, args=(i,)) for i in range(count)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=30)
    for result in results:
        if isinstance(result, Exception):
            raise result
    return results


def _slow_build(calls: list, make):
    def build(*args):
        calls.append(args)
        time.sleep(0.2)  # long enough for every other caller to arrive while it builds
        make(*args)
    return build


def test_one_holder_at_a_time(tmp_path):
    inside, most = [0], [0]

    def hold():
        with exclusive(tmp_path / "locks" / "x.lock"):
            inside[0] += 1
            most[0] = max(most[0], inside[0])
            time.sleep(0.05)
            inside[0] -= 1

    _at_once(hold, 4)
    assert most[0] == 1 and (tmp_path / "locks" / "x.lock").is_file()


def test_the_windows_python_is_prepared_once_for_callers_at_once(tmp_path, monkeypatch):
    monkeypatch.setenv("NFAL_CACHE_DIR", str(tmp_path))
    calls = []

    def make(root: Path):
        root.mkdir(parents=True)
        (root / "python.exe").write_bytes(b"MZ")

    monkeypatch.setattr(windows_python, "_prepare", _slow_build(calls, make))
    roots = _at_once(windows_python.windows_python)
    assert len(calls) == 1 and len(set(roots)) == 1 and (roots[0] / "python.exe").is_file()


@pytest.mark.parametrize("fmi_version", [2, 3])
def test_the_runtime_is_built_once_for_callers_at_once(fmi_version, tmp_path, monkeypatch):
    monkeypatch.setenv("NFAL_CACHE_DIR", str(tmp_path))
    calls = []
    monkeypatch.setattr(export_runtime, "_build_runtime",
                        _slow_build(calls, lambda runtime, target: target.write_bytes(b"\x7fELF")))
    libraries = _at_once(lambda: export_runtime.runtime_library(fmi_version))
    assert len(calls) == 1 and len(set(libraries)) == 1 and libraries[0].read_bytes() == b"\x7fELF"


def test_a_build_of_the_same_sources_is_a_copy_and_another_nfal_version_a_new_build(tmp_path, monkeypatch):
    monkeypatch.setattr(build, "cache_root", lambda: tmp_path / "cache")  # the FMUs' (the runtime's stays warm)
    touched = tmp_path / "touched.py"  # a source, saved again after the first build with its content unchanged
    touched.write_text("")
    sources = build.sources
    monkeypatch.setattr(build, "sources", lambda *args: [*sources(*args), touched])
    first = build.build_fmu("ReferenceGenerator", tmp_path / "a")
    os.utime(touched, (first.stat().st_mtime + 1e-3,) * 2)
    monkeypatch.setattr(build.Fmi2Builder, "build_FMU", _refuse)
    again = build.build_fmu("ReferenceGenerator", tmp_path / "b")
    assert again != first and again.read_bytes() == first.read_bytes()
    # a new file, not as old as the cached build: newer than its sources (and than what was packed from an older one)
    assert build.is_up_to_date(again, "ReferenceGenerator")
    monkeypatch.setattr(nfal, "__version__", "9.9.9")  # carried by the FMU: another build
    with pytest.raises(AssertionError, match="the builder ran"):
        build.build_fmu("ReferenceGenerator", tmp_path / "c")


def test_the_c_host_is_compiled_once_and_copied(tmp_path, monkeypatch):
    monkeypatch.setattr(host_check, "cache_root", lambda: tmp_path / "cache")
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
    first = host_check.compile_c_host(tmp_path / "a", 2)
    monkeypatch.setattr(host_check.subprocess, "run", _refuse)
    again = host_check.compile_c_host(tmp_path / "b", 2)
    assert again.parent == tmp_path / "b" and again.read_bytes() == first.read_bytes()
    assert os.access(again, os.X_OK)


def _refuse(*args, **kwargs):
    raise AssertionError("the builder ran")


def test_a_c_host_whose_header_changed_is_compiled_again(tmp_path, monkeypatch):
    monkeypatch.setattr(host_check, "cache_root", lambda: tmp_path / "cache")
    sources = tmp_path / "hosts"
    shutil.copytree(host_check.C_HOST_SOURCES[2].parent, sources)
    monkeypatch.setitem(host_check.C_HOST_SOURCES, 2, sources / "fmi2_host.c")
    compiled, run = [], subprocess.run
    monkeypatch.setattr(host_check.subprocess, "run", lambda command, **kw: compiled.append(1) or run(command, **kw))
    for edit in ("", "", "/* edited */\n"):
        with open(sources / "host_common.h", "a") as header:
            header.write(edit)
        host_check.compile_c_host(tmp_path, 2)
    assert len(compiled) == 2  # the first time, and after the edit


def test_the_newest_builds_of_each_fmu_are_kept(tmp_path):
    for k in range(build.KEPT_BUILDS + 3):
        entry = tmp_path / f"key{k}" / "X.fmu"
        entry.parent.mkdir()
        entry.write_bytes(b"x")
        os.utime(entry, (1000 + k,) * 2)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "Y.fmu").write_bytes(b"y")
    build._prune(tmp_path, "X.fmu")
    assert sorted(p.parent.name for p in tmp_path.glob("*/X.fmu")) == sorted(f"key{k}" for k in range(3, 11))
    assert (tmp_path / "other" / "Y.fmu").is_file()


def test_a_write_in_one_step_that_fails_leaves_the_old_file_and_nothing_else(tmp_path):
    target = tmp_path / "x.fmu"
    target.write_bytes(b"old")

    def fail(path):
        path.write_bytes(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_in_one_step(target, fail)
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["x.fmu"]
    write_in_one_step(target, lambda path: path.write_bytes(b"new"))
    assert target.read_bytes() == b"new" and sorted(p.name for p in tmp_path.iterdir()) == ["x.fmu"]


@pytest.mark.slow  # seven FMUs built (a few seconds)
def test_a_command_says_each_fmu_it_builds_and_nothing_for_copies_from_the_cache(tmp_path, monkeypatch, caplog):
    """A first build took 20-30 s without a line; the command line now shows the build's INFO lines, and only for
    work that is not a copy."""
    from nfal.cli import BUILD_LOGGERS, main

    monkeypatch.setattr(build, "cache_root", lambda: tmp_path / "cache")  # the FMUs' (the runtime's stays warm)
    caplog.set_level("WARNING")  # the root logger as the command line sets it without -v
    caplog.handler.setLevel(logging.NOTSET)  # and every record that gets past the loggers captured
    said = []
    for out in ("a", "b"):
        caplog.clear()
        assert main(["build", "--out", str(tmp_path / out)]) == 0
        said.append([record.getMessage() for record in caplog.records if record.name in BUILD_LOGGERS])
    assert sum(message.startswith("building ") for message in said[0]) == len(build.FMU_SCRIPTS)
    assert said[1] == []  # every FMU a copy from the cache
    assert all(logging.getLogger(name).level == logging.NOTSET for name in BUILD_LOGGERS)  # restored afterwards
