"""``nfal <command>`` in a process of its own, forked from a warm one: the suite's rig emulators.

Each ``python -m nfal rig-emulator`` pays the interpreter's start, nfal's imports and numba's (its import and the
kernels' load): 1.3-1.8 s of CPU here before it prints its port (``python bench/bench_startup.py``), for each of
the suite's emulators. Here multiprocessing's fork server imports all that once per test worker (:data:`PRELOAD`)
and forks each command from it (``python -m pytest -n 0 tests/test_hil_end_to_end.py``: 62.6 s before, 32.7 s
after, 2026-11-28). What runs is the CLI's own ``main(argv)``, in a process of its own (its pid, signals, exit
code); only the interpreter's start and the imports are shared. A test of the command line itself (its start, its
imports) starts ``python -m nfal`` as a user does, not this.
"""

from __future__ import annotations

import multiprocessing
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

#: What the fork server imports before it forks: the emulator's command and the kernels of its plant.
PRELOAD = ["nfal.cli", "nfal.cli.commands.hil", "nfal.apps.rig_emulator_session"]
_CONTEXT = multiprocessing.get_context("forkserver")
_CONTEXT.set_forkserver_preload(PRELOAD)


def _run(argv: list[str], environment: dict[str, str], cwd: str, stdout: str, stderr: str) -> None:
    """In the forked process: the command line's streams to the files, the caller's environment, ``main``."""
    for fd, path in ((1, stdout), (2, stderr)):
        opened = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(opened, fd)
        os.close(opened)
    os.environ.clear()
    os.environ.update(environment)
    os.chdir(cwd)
    sys.argv = ["nfal", *argv]
    from nfal.cli import main

    code = main(argv)
    sys.stdout.flush()
    sys.stderr.flush()
    sys.exit(code)


class WarmProcess:
    """``nfal *argv`` forked from the warm server, with what the tests use of a ``subprocess.Popen``: its streams go
    to files in a folder of its own, read by :meth:`readline` while it runs and by :meth:`communicate` at its end
    (which removes the folder)."""

    def __init__(self, argv: list[str]) -> None:
        self._folder = Path(tempfile.mkdtemp(prefix="nfal-warm-"))
        self._out, self._err = self._folder / "stdout", self._folder / "stderr"
        # daemonic: ended with the test worker if a test left it running
        self._process = _CONTEXT.Process(target=_run, args=(list(argv), dict(os.environ), os.getcwd(),
                                                            str(self._out), str(self._err)), daemon=True)
        self._process.start()
        self.pid = self._process.pid
        self._read = 0
        self._streams: tuple[str, str] | None = None

    def readline(self, timeout_s: float = 60.0) -> str:
        """The next whole line of its output, or "" once it has ended (or after ``timeout_s``) without one."""
        deadline = time.monotonic() + timeout_s
        while True:
            text = self._out.read_text() if self._out.exists() else ""
            end = text.find("\n", self._read)
            if end >= 0:
                line, self._read = text[self._read:end + 1], end + 1
                return line
            if not self._process.is_alive() or time.monotonic() > deadline:
                return ""
            time.sleep(0.01)

    @property
    def returncode(self) -> int | None:
        return self._process.exitcode

    def poll(self) -> int | None:
        return self._process.exitcode

    def send_signal(self, number: int) -> None:
        if self._process.exitcode is None:
            os.kill(self.pid, number)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def communicate(self, timeout: float | None = None) -> tuple[str, str]:
        """Wait for the end (killed after ``timeout``, as a test's bound): the output after what :meth:`readline`
        gave, and the error stream (the same again when called again)."""
        if self._streams is None:
            self._process.join(timeout)
            if self._process.exitcode is None:
                self.kill()
                self._process.join()
                raise TimeoutError(f"nfal (pid {self.pid}) did not end within {timeout} s")
            self._streams = self._out.read_text()[self._read:], self._err.read_text()
            shutil.rmtree(self._folder, ignore_errors=True)
        return self._streams
