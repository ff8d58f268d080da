"""Sweeps: many runs of a :mod:`~nfal.orchestration.sweep_spec` spec on a Dask cluster, one results table.

:func:`run_sweep` expands the spec, skips the runs already in ``out_dir/results.csv``, and submits the
others to a :class:`dask.distributed.Client`: a local cluster of ``workers`` single-threaded processes
by default, or the scheduler at ``scheduler``. Nothing needs a shared file system: an SSP archive is
scattered to every worker once (``broadcast=True``) with its sha256; the first task on a machine
checks the hash and unpacks it, FMUs included, into a local cache (``<tmp>/nfal-sweep-cache/<sha256>/``),
which later tasks reuse (they check the hash of the bytes they hold, and the cache's marker). The files the
spec's values name (:attr:`~.sweep_spec.SweepSpec.files`, resolved from the spec's folder) travel the same way:
scattered once with their sha256, written to ``<tmp>/nfal-sweep-cache/files/<sha256>/<name>``, and each run's
value is replaced by that worker-local path (:func:`localised`) before its task runs.

Every finished run is appended to ``results.csv`` at once (flushed), as one row: run id, status, error,
warnings, wall time, the swept parameters and the kind's metrics. A run that raises is a row with status
"failed" and its error; the sweep goes on. A task may return ``warnings`` (text) with its metrics: the run
is "ok" with warnings, as ``nfal run``'s status rule has it (:mod:`.checks`). Written as well: ``spec.json``
(the expanded spec), ``summary.json`` and ``sweep.png`` (each metric over each swept parameter, :mod:`.sweep_plot`).

What a run is comes from the spec's :class:`~.sweep_spec.SweepKind` (its task and metric columns):
this engine knows no kind of its own (nfal's kinds: :mod:`nfal.apps.sweeps`).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import hashlib
import io
import json
import logging
import os
import shutil
import socket
import sys
import tempfile
import time
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path

from tqdm import tqdm

from nfal.errors import SweepError, SweepSpecError

from .sweep_plot import plot_sweep
from .sweep_spec import RunSpec, SweepSpec, canonical_json, map_strings

logger = logging.getLogger(__name__)

RESULTS_CSV, SUMMARY_JSON, SPEC_JSON, SWEEP_PNG = "results.csv", "summary.json", "spec.json", "sweep.png"
FIXED_COLUMNS = ("run_id", "index", "status", "error", "warnings", "wall_time_s", "worker")
TEXT_COLUMNS = ("run_id", "status", "error", "warnings", "worker")
CACHE_DIR_NAME = "nfal-sweep-cache"


def metric_columns(spec: SweepSpec) -> tuple[str, ...]:
    """The metric columns of ``spec``'s kind (SI; the unit ends the name)."""
    return tuple(spec.kind.metrics(spec.settings))


def columns(spec: SweepSpec) -> list[str]:
    """The header of ``results.csv``: fixed columns, swept parameters, metrics."""
    return list(FIXED_COLUMNS) + [f"param:{n}" for n in spec.swept_names] + list(metric_columns(spec))


# ---------------------------------------------------------------------------------------------- tasks

def cached_structure(data: bytes, sha256: str, cache_dir: str | os.PathLike | None = None) -> Path:
    """The worker-local SSP folder of the archive ``data``, unpacked once after checking its sha256.

    The archive is unpacked into ``<cache>/<sha256>/`` with every ``.fmu`` in it unpacked in place (a
    folder of the same name), so that runs neither unzip the archive nor extract the FMUs again. The
    folder is complete when its ``.sha256`` file holds the hash; it is built in a temporary folder
    and renamed, so worker processes sharing the cache do not race.
    """
    cache = _checked_cache(data, sha256, "the archive", cache_dir)
    folder = cache / sha256
    if _complete(folder, sha256):
        return folder
    cache.mkdir(parents=True, exist_ok=True)
    temp = Path(tempfile.mkdtemp(dir=cache, prefix=".part-"))
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            archive.extractall(temp)
        for fmu in list(temp.rglob("*.fmu")):
            if fmu.is_file() and zipfile.is_zipfile(fmu):
                packed = fmu.with_name(fmu.name + ".zip")
                fmu.rename(packed)
                with zipfile.ZipFile(packed) as archive:
                    archive.extractall(fmu)
                packed.unlink()
        (temp / ".sha256").write_text(sha256 + "\n")
        # a folder renamed in holds its marker from the start, so one without it is an interrupted unpack of an
        # earlier version, which no run uses: set aside in one step (a complete one, renamed in meanwhile by another
        # process, is in use and is never removed)
        if folder.exists() and not _complete(folder, sha256):
            stale = Path(tempfile.mkdtemp(dir=cache, prefix=".stale-"))
            with contextlib.suppress(FileNotFoundError):  # another process set it aside first
                os.rename(folder, stale / "folder")
            shutil.rmtree(stale, ignore_errors=True)
        os.rename(temp, folder)
    except OSError:
        shutil.rmtree(temp, ignore_errors=True)
        if not _complete(folder, sha256):  # not another process's win
            raise
    except zipfile.BadZipFile as exc:
        shutil.rmtree(temp, ignore_errors=True)
        raise SweepError(f"the archive {sha256[:12]}... is not a zip (SSP) archive: {exc}") from None
    return folder


def _complete(folder: Path, sha256: str) -> bool:
    """Whether ``folder`` is a whole unpack of the archive ``sha256`` (its marker holds the hash)."""
    marker = folder / ".sha256"
    try:
        return marker.read_text().strip() == sha256
    except OSError:
        return False


def _checked_cache(data: bytes, sha256: str, what: str, cache_dir: str | os.PathLike | None) -> Path:
    """The worker cache folder, once ``data`` (``what``) is checked to have the hash ``sha256``."""
    actual = hashlib.sha256(data).hexdigest()
    if actual != sha256:
        raise SweepError(f"{what} arrived with sha256 {actual}, not {sha256}: refusing to run it")
    return Path(cache_dir) if cache_dir is not None else Path(tempfile.gettempdir()) / CACHE_DIR_NAME


def cached_file(data: bytes, sha256: str, name: str, cache_dir: str | os.PathLike | None = None) -> Path:
    """The worker-local copy of a file a spec names, ``<cache>/files/<sha256>/<name>``, written once after checking
    its sha256 (through a temporary file and a rename: there is no partial file, and worker processes sharing the
    cache do not race)."""
    folder = _checked_cache(data, sha256, f"the file {name}", cache_dir) / "files" / sha256
    path = folder / name
    if path.is_file():
        return path
    folder.mkdir(parents=True, exist_ok=True)
    handle, temp = tempfile.mkstemp(dir=folder, prefix=".part-")
    with os.fdopen(handle, "wb") as stream:
        stream.write(data)
    os.replace(temp, path)
    return path


def shipped_files(spec: SweepSpec) -> dict:
    """What :func:`localised` takes: ``{(name, value): (prefix, file name, sha256, bytes)}`` of the spec's files."""
    shipped = {}
    for key, (prefix, path) in spec.files.items():
        data = path.read_bytes()
        shipped[key] = (prefix, path.name, hashlib.sha256(data).hexdigest(), data)
    return shipped


def localised(run: RunSpec, files: Mapping, cache_dir: str | os.PathLike | None = None) -> RunSpec:
    """``run`` with each value that names a shipped file (:func:`shipped_files`) replaced by its worker-local copy."""
    def change(key: str, value: str) -> str:
        if (key, value) not in files:
            return value
        prefix, name, sha, data = files[(key, value)]
        return prefix + str(cached_file(data, sha, name, cache_dir))

    return dataclasses.replace(run, parameters=map_strings(run.parameters, change),
                               settings=map_strings(run.settings, change))


def run_task(run: RunSpec, task: Callable[[RunSpec, Path | None], dict], archive: bytes | None = None,
             sha256: str | None = None, files: Mapping | None = None) -> dict:
    """Run one run of a sweep with its kind's ``task`` and return its row (status "failed" and the error if
    it raised); ``archive`` (an SSP archive's bytes) is unpacked into the worker cache first, and the ``files``
    the run's values name (:func:`shipped_files`) are written there, the values pointing at them."""
    started = time.perf_counter()
    row = {"run_id": run.run_id, "index": run.index, "status": "ok", "error": "", "worker": socket.gethostname()
           + f":{os.getpid()}"}
    try:
        structure = cached_structure(archive, sha256) if archive is not None else None
        row.update(task(localised(run, files) if files else run, structure))
    except Exception as exc:  # noqa: BLE001 - a failed run is a row, not a dead sweep
        row.update(status="failed", error=f"{type(exc).__name__}: {exc}")
    row["wall_time_s"] = time.perf_counter() - started
    return row


# ---------------------------------------------------------------------------------------------- table

def _format(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, dict)):
        return canonical_json(value)
    return str(value).replace("\n", " ")


class ResultsTable:
    """``results.csv``: one row per finished run, appended and flushed as each finishes."""

    def __init__(self, path: Path, header: list[str]) -> None:
        self.path = path
        self.header = header
        self.finished: dict[str, dict] = {}
        if path.exists() and path.stat().st_size:
            self._recover()
        else:
            path.write_text(",".join(header) + "\n", encoding="utf-8")
        self._handle = path.open("a", encoding="utf-8", newline="")
        self._writer = csv.DictWriter(self._handle, fieldnames=header, lineterminator="\n")

    def _recover(self) -> None:
        data = self.path.read_bytes()
        if not data.endswith(b"\n"):  # the last row was cut off mid-write: drop it (that run is redone)
            data = data[: data.rfind(b"\n") + 1]
            self.path.write_bytes(data)
        reader = csv.reader(io.StringIO(data.decode("utf-8")))
        found = next(reader, None)
        if found != self.header:
            raise SweepError(f"{self.path} holds another sweep's table (its columns differ from this spec's); "
                             "use another --out folder")
        for fields in reader:
            if len(fields) == len(self.header):
                row = dict(zip(self.header, fields))
                self.finished[row["run_id"]] = row

    def append(self, row: Mapping) -> None:
        self._writer.writerow({k: _format(row.get(k)) for k in self.header})
        self._handle.flush()
        self.finished[row["run_id"]] = dict(row)

    def close(self) -> None:
        self._handle.close()


def read_table(path: str | os.PathLike) -> list[dict]:
    """``results.csv`` as dicts: numbers as float, empty as None, sorted by run index."""
    rows = []
    with open(path, encoding="utf-8", newline="") as handle:
        for row in csv.DictReader(handle):
            out = {}
            for key, text in row.items():
                if text == "" or text is None:
                    out[key] = None
                elif key in TEXT_COLUMNS:
                    out[key] = text
                else:
                    try:
                        out[key] = float(text)
                    except ValueError:
                        out[key] = text
            rows.append(out)
    return sorted(rows, key=lambda r: r["index"])


# ---------------------------------------------------------------------------------------------- engine

@dataclasses.dataclass
class SweepResult:
    """What a sweep wrote and did: the folder, the table, the counts and the summary."""

    out_dir: Path
    csv_path: Path
    plot_path: Path | None
    summary: dict

    def rows(self) -> list[dict]:
        """Every row of ``results.csv`` (by run index), including rows of other specs' runs if any."""
        return read_table(self.csv_path)


def _archive_path(spec: SweepSpec, archives: Mapping[str, os.PathLike] | None) -> Path:
    structure = str(spec.settings["structure"])
    if archives and structure in archives:
        return Path(archives[structure])
    path = Path(structure)
    if not path.is_absolute():
        path = spec.base_dir / path
    if not path.is_file():
        known = ", ".join(archives or ()) or "none given"
        raise SweepError(f"[run] structure = {structure!r}: no such .ssp archive ({path}); built-in: {known}")
    if not zipfile.is_zipfile(path):
        raise SweepError(f"[run] structure = {structure!r}: {path} is not an .ssp archive (a zip file)")
    return path


class _InProcess:
    """``workers=0``: the tasks run one after another in this process, each when its result is collected, with no
    Dask at all (tests, a debugger's breakpoints). What :func:`run_sweep` uses of a Dask client."""

    def scheduler_info(self) -> dict:
        return {"workers": {"in-process": {}}}

    def scatter(self, data, broadcast: bool = True):
        return data

    def submit(self, function, *args, pure: bool = False) -> "_Deferred":
        return _Deferred(function, args)

    def close(self) -> None:
        pass


@dataclasses.dataclass
class _Deferred:
    """A task of :class:`_InProcess`: run when its result is asked for."""

    function: object
    args: tuple

    def result(self):
        return self.function(*self.args)


def _client(scheduler: str | None, workers: int | None):
    if workers == 0 and not scheduler:  # in this process: no cluster, no event loop to start
        return _InProcess(), None
    from dask.distributed import Client, LocalCluster  # on use: Dask takes a second to import

    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError, ValueError) as exc:  # ValueError: not an address (no port, unknown protocol)
            raise SweepError(f"cannot reach the Dask scheduler at {scheduler!r} (expected tcp://host:port): "
                             f"{exc}") from None
    # the scheduler's HTTP server starts whatever dashboard_address says (None does not stop it: dask/distributed
    # issue 8136); ":0" takes a free port, so a second cluster (another sweep, a notebook's) does not warn of 8787
    cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=logging.ERROR)
    return Client(cluster), cluster


def run_sweep(spec: SweepSpec, out_dir: str | os.PathLike, *, scheduler: str | None = None, workers: int | None = None,
              archives: Mapping[str, os.PathLike] | None = None, progress: bool | None = None, plot: bool = True,
              on_row: Callable[[dict], None] | None = None) -> SweepResult:
    """Run every run of ``spec`` not yet in ``out_dir/results.csv``; append each row as it finishes.

    Parameters
    ----------
    spec : SweepSpec
        From :func:`~nfal.orchestration.sweep_spec.load_spec`.
    out_dir : path-like
        Result folder (created). A ``results.csv`` already there from the same spec is continued.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:port``); default: a local cluster.
    workers : int, optional
        Worker processes of the local cluster (default: this machine's cores); 0: the runs one after another in
        this process, without Dask (tests, a debugger). Ignored with ``scheduler``.
    archives : mapping, optional
        Built-in structure name -> ``.ssp`` path (the CLI builds them); other ``structure`` values are paths.
    progress : bool, optional
        A tqdm bar on stderr; default: only when stderr is a terminal.
    plot : bool
        Write ``sweep.png`` at the end.
    on_row : callable, optional
        Called with each new row after it is written.

    Raises
    ------
    SweepError
        The folder holds another sweep's table, the archive is missing, or the scheduler is unreachable.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = spec.runs()
    header = columns(spec)
    table = ResultsTable(out / RESULTS_CSV, header)
    todo = [r for r in runs if r.run_id not in table.finished]
    skipped = len(runs) - len(todo)
    foreign = len(set(table.finished) - {r.run_id for r in runs})
    if foreign:
        logger.warning("%s holds %d rows of runs this spec does not have (its run settings or values changed); "
                       "they are kept", table.path, foreign)
    _write_spec(out / SPEC_JSON, spec, runs)
    summary = {"name": spec.name, "kind": spec.kind.name, "runs": len(runs), "skipped": skipped, "other_rows": foreign,
               "new": 0, "ok": 0, "with_warnings": 0, "failed": 0,
               "status": "running", "scheduler": scheduler or "local", "workers": None,
               "wall_time_s": 0.0, "task_wall_time_s": 0.0}
    logger.info("%s: %d runs, %d already finished in %s", spec.name, len(runs), skipped, out)
    started = time.perf_counter()
    client = cluster = None
    bar = tqdm(total=len(runs), initial=skipped, desc=spec.name, unit="run", file=sys.stderr,
               disable=not (progress if progress is not None else sys.stderr.isatty()))
    try:
        if todo:
            archive = sha = files = None
            if spec.kind.needs_archive:
                data = _archive_path(spec, archives).read_bytes()
                sha = hashlib.sha256(data).hexdigest()
            shipped = shipped_files(spec)
            client, cluster = _client(scheduler, workers)
            summary["workers"] = len(client.scheduler_info().get("workers", {}))
            if spec.kind.needs_archive:
                archive = client.scatter(data, broadcast=True)  # once per worker, not per task
            if shipped:
                [files] = client.scatter([shipped], broadcast=True)  # as the archive: once per worker
            futures = [client.submit(run_task, run, spec.kind.task, archive, sha, files, pure=False) for run in todo]
            for run, row in _as_finished(futures, todo):
                table.append(row)
                summary["new"] += 1
                summary["task_wall_time_s"] += row.get("wall_time_s") or 0.0
                bar.update(1)
                if on_row is not None:
                    on_row(row)
        summary["status"] = "ok"
    except BaseException as exc:
        summary["status"] = "interrupted" if isinstance(exc, KeyboardInterrupt) else "failed"
        summary["error"] = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        bar.close()
        table.close()
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        summary["wall_time_s"] = time.perf_counter() - started
        rows = _close_summary(out, summary, runs)
    plot_path = None
    if plot:
        try:
            plot_path = plot_sweep(spec, rows, list(metric_columns(spec)), out / SWEEP_PNG)
        except Exception as exc:  # a plot must not hide the sweep's outcome
            logger.warning("no sweep plot: %s", exc)
    return SweepResult(out, out / RESULTS_CSV, plot_path, summary)


def _write_spec(path: Path, spec: SweepSpec, runs: list[RunSpec]) -> None:
    """``spec.json``: the expanded spec, every run with its id and parameters."""
    path.write_text(json.dumps({"name": spec.name, "kind": spec.kind.name, "settings": spec.settings, "grid": spec.grid,
                                "random": spec.random, "draws": spec.draws, "seed": spec.seed,
                                "runs": [dataclasses.asdict(r) | {"settings": None} for r in runs]}, indent=2) + "\n")


def _as_finished(futures, todo: list[RunSpec]):
    """(run, row) as each task finishes; a task that died (worker lost) is a failed row."""
    for future, run in _finishing(futures, todo):
        try:
            row = future.result()
        except Exception as exc:  # noqa: BLE001 - the task died: a failed row, the sweep goes on
            row = {"run_id": run.run_id, "index": run.index, "status": "failed",
                   "error": f"{type(exc).__name__}: {exc}", "wall_time_s": None, "worker": ""}
        row.update({f"param:{k}": v for k, v in run.parameters.items()})
        if row["status"] != "ok":
            logger.warning("run %s (%s) failed: %s", run.run_id, canonical_json(run.parameters), row["error"])
        yield run, row


def _finishing(futures, todo: list[RunSpec]):
    """(future, run) in the order the tasks finish: in-process tasks in order, Dask's as they complete."""
    if all(isinstance(future, _Deferred) for future in futures):
        yield from zip(futures, todo)
        return
    from dask.distributed import as_completed  # on use: Dask takes a second to import

    by_future = {f.key: r for f, r in zip(futures, todo)}
    for future in as_completed(futures):
        yield future, by_future[future.key]


def _close_summary(out: Path, summary: dict, runs: list[RunSpec]) -> list[dict]:
    """Count this spec's rows in ``results.csv`` into the summary, write ``summary.json``; return the rows."""
    ids = {r.run_id for r in runs}
    rows = [r for r in read_table(out / RESULTS_CSV) if r["run_id"] in ids]
    summary["ok"] = sum(r["status"] == "ok" for r in rows)
    summary["with_warnings"] = sum(r["status"] == "ok" and bool(r.get("warnings")) for r in rows)
    summary["failed"] = sum(r["status"] != "ok" for r in rows)
    summary["finished"] = len(rows)
    (out / SUMMARY_JSON).write_text(json.dumps(summary, indent=2, default=str) + "\n")
    return rows


__all__ = ["ResultsTable", "SweepError", "SweepResult", "SweepSpecError", "cached_file", "cached_structure", "columns",
           "localised", "metric_columns", "plot_sweep", "read_table", "run_sweep", "run_task", "shipped_files"]
