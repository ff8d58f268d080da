"""``nfal <command>`` in a process of its own, forked from a warm one: the suite's rig emulators, and the command
lines its tests start to signal, limit or crash.

Each ``python -m nfal`` pays the interpreter's start, nfal's imports and numba's (its import and the kernels' load):
1.3-1.8 s of CPU here before ``nfal rig-emulator`` prints its port (``python bench/bench_startup.py``), for each of
the suite's emulators. Here multiprocessing's fork server imports all that once per test worker (:data:`PRELOAD`)
and forks each command from it (``python -m pytest -n 0 tests/test_hil_end_to_end.py``: 62.6 s before, 32.7 s
after, 2026-11-28). What runs is the CLI's own ``main(argv)``, in a process of its own (its pid, its session if
asked, signals, resource limits, exit code); only the interpreter's start and the imports are shared. What a fork
skips is the interpreter's finalisation at exit (multiprocessing ends the child with ``os._exit``): a test of the
command line's start, its imports or its exit starts ``python -m nfal`` as a user does (:func:`popen`, for any
other command), not this.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from unittest import mock

#: What the fork server imports before it forks: the commands the suite starts this way and the kernels of the
#: emulator's plant, compiled (multiprocessing skips a preload module it cannot import: ``test_warm_nfal.py`` checks).
PRELOAD = ["nfal.cli", "nfal.cli.commands.hil", "nfal.cli.commands.identify", "nfal.cli.commands.cosim",
           "nfal.apps.rig_emulator_session", "helpers.compiled_kernels"]
_CONTEXT = multiprocessing.get_context("forkserver")
_CONTEXT.set_forkserver_preload(PRELOAD)
#: How ``python -m nfal`` starts in a command line (what :func:`popen` forks instead).
NFAL = [sys.executable, "-m", "nfal"]


def _start_server() -> None:
    """Start the fork server (once) with ``helpers`` importable for its preload: Python 3.11's fork server ignores the
    sys.path it is sent, and its own starts from the working folder."""
    tests = str(Path(__file__).resolve().parent.parent)
    with mock.patch.dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [tests, os.environ.get("PYTHONPATH")]))):
        multiprocessing.forkserver.ensure_running()


def _run(argv: list[str], environment: dict[str, str], cwd: str, stdout: str, stderr: str, new_session: bool,
         preexec_fn: Callable[[], None] | None) -> None:
    """In the forked process: the command line's streams to the files, the caller's environment, ``main``."""
    # may start processes of its own (a sweep's local cluster), as the command line can: the daemon flag (which only
    # has the worker end it with itself) would refuse that
    multiprocessing.current_process().daemon = False
    for fd, path in ((1, stdout), (2, stderr)):
        opened = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(opened, fd)
        os.close(opened)
    os.environ.clear()
    os.environ.update(environment)
    os.chdir(cwd)
    if new_session:  # then preexec_fn, in Popen's order
        os.setsid()
    if preexec_fn is not None:
        preexec_fn()
    sys.argv = ["nfal", *argv]
    from nfal.cli import main

    code = main(argv)
    sys.stdout.flush()
    sys.stderr.flush()
    sys.exit(code)


class _Output:
    """A stream of the process as a file it writes: whole lines while it runs (``readline``), the rest at its end."""

    def __init__(self, path: Path, running: Callable[[], bool]) -> None:
        self.path, self._running, self._read = path, running, 0

    def _text(self) -> str:
        return self.path.read_text() if self.path.exists() else ""

    def readline(self, timeout_s: float = 60.0) -> str:
        """The next whole line, or "" once the process has ended (or after ``timeout_s``) without one."""
        deadline = time.monotonic() + timeout_s
        while True:
            text = self._text()
            end = text.find("\n", self._read)
            if end >= 0:
                line, self._read = text[self._read:end + 1], end + 1
                return line
            if not self._running() or time.monotonic() > deadline:
                return ""
            time.sleep(0.01)

    def rest(self) -> str:
        return self._text()[self._read:]


class WarmProcess:
    """``nfal *argv`` forked from the warm server, with what the tests use of a ``subprocess.Popen``: ``stdout`` and
    ``stderr`` go to files in a folder of its own, read line by line while it runs (``stdout.readline``) and whole by
    :meth:`communicate` at its end (which removes the folder). ``cwd``, ``env``, ``start_new_session`` and
    ``preexec_fn`` (picklable) are Popen's."""

    def __init__(self, argv: list[str], *, cwd: str | Path | None = None, env: dict[str, str] | None = None,
                 start_new_session: bool = False, preexec_fn: Callable[[], None] | None = None) -> None:
        self.args = ["nfal", *argv]
        self._folder = Path(tempfile.mkdtemp(prefix="nfal-warm-"))
        _start_server()
        # daemonic: ended with the test worker if a test left it running
        self._process = _CONTEXT.Process(
            target=_run, daemon=True,
            args=(list(argv), dict(os.environ if env is None else env), str(cwd or os.getcwd()),
                  str(self._folder / "stdout"), str(self._folder / "stderr"), start_new_session, preexec_fn))
        self._process.start()
        self.pid = self._process.pid
        self.stdout = _Output(self._folder / "stdout", self._process.is_alive)
        self.stderr = _Output(self._folder / "stderr", self._process.is_alive)
        self._streams: tuple[str, str] | None = None

    @property
    def returncode(self) -> int | None:
        return self._process.exitcode

    def poll(self) -> int | None:
        return self._process.exitcode

    def wait(self, timeout: float | None = None) -> int:
        self._process.join(timeout)
        if self._process.exitcode is None:
            raise subprocess.TimeoutExpired(self.args, timeout)
        return self._process.exitcode

    def send_signal(self, number: int) -> None:
        if self._process.exitcode is None:
            os.kill(self.pid, number)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def communicate(self, timeout: float | None = None) -> tuple[str, str]:
        """Wait for the end (``subprocess.TimeoutExpired`` after ``timeout``, the process left running, as Popen's):
        the output after what ``stdout.readline`` gave, and the error stream (the same again when called again)."""
        if self._streams is None:
            self.wait(timeout)
            self._streams = self.stdout.rest(), self.stderr.rest()
            shutil.rmtree(self._folder, ignore_errors=True)
        return self._streams


def popen(command: list[str], **options) -> WarmProcess | subprocess.Popen:
    """``python -m nfal ...`` (:data:`NFAL`) forked warm with Popen's ``cwd``, ``env``, ``preexec_fn`` and
    ``start_new_session`` (its streams always to files); any other command (a script, an FMU driven by fmpy) started
    by ``subprocess.Popen(command, **options)``."""
    if command[:len(NFAL)] != NFAL:
        return subprocess.Popen(command, **options)
    return WarmProcess(command[len(NFAL):], cwd=options.get("cwd"), env=options.get("env"),
                       start_new_session=options.get("start_new_session", False),
                       preexec_fn=options.get("preexec_fn"))
