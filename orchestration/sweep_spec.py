"""Sweep specifications: a TOML file naming what each run is and the values its parameters take.

A spec has a ``[run]`` table (``kind`` and that kind's settings), and a ``[grid]`` (name -> list of
values: every combination is run) and/or a ``[random]`` table (``draws`` and ``seed``, and name ->
``{distribution, ...}``: ``draws`` seeded draws, combined with every grid point)::

    [sweep]
    name = "robustness"              # optional; used in plot titles

    [run]
    kind = "ssp"                     # a kind of the registry given to load_spec (nfal's: nfal/apps/sweeps.py)
    structure = "fig7_slow"          # built-in structure or path of an .ssp (relative to the spec)
    stop_time = 0.4
    reference = {levels_m = [100e-6, 140e-6], hold_s = 0.3, lead_s = 0.1}

    [grid]
    "Plant.mass" = [0.108, 0.1347, 0.162]
    "SensorChain.seed" = [0, 1]

    [random]
    draws = 4
    seed = 1
    "ResonanceTracker.resonance_frequency" = {distribution = "uniform", low = 28400, high = 28600}

Distributions: ``uniform`` (low, high), ``loguniform`` (low, high > 0), ``normal`` (mean, std),
``integers`` (low, high, both included). Each run gets a stable id: a hash of the canonical JSON of
its run settings and parameters, so the same spec expands to the same ids on every machine.

Paths in a spec are relative to the spec's folder: ``structure``, and every string value (a ``[run]`` setting
at any depth, or a ``[grid]`` value) that the kind's ``file_in`` says names a file. Each such file must exist
when the spec is read; it is kept in :attr:`SweepSpec.files` and shipped to the workers with the runs
(:mod:`.sweep`), while the runs keep the value as written (their ids do not depend on where the spec lies).

What a run *is* comes from a registry of :class:`SweepKind` (name -> settings, sweepable names, task,
metric columns) that the caller passes in: this module and :mod:`.sweep` know no kind of their own.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import os
import sys
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from nfal.errors import SweepSpecError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

#: Largest spec file read (a grid of 100 000 runs fits in a few MiB).
MAX_SPEC_BYTES = 16 << 20
DISTRIBUTIONS = {"uniform": ("low", "high"), "loguniform": ("low", "high"), "normal": ("mean", "std"),
                 "integers": ("low", "high")}


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: its id, its swept parameters, and the run settings they apply to."""

    run_id: str
    index: int
    parameters: dict
    settings: dict


@dataclasses.dataclass(frozen=True)
class SweepKind:
    """What the runs of a sweep are; a registry maps ``[run] kind`` names onto these.

    Attributes
    ----------
    name : str
        The ``[run] kind`` value.
    settings : mapping
        The ``[run]`` keys the kind takes (besides ``kind``), with their defaults.
    task : callable
        ``task(run, structure) -> {metric: value}``: one run; ``structure`` is the unpacked SSP archive's
        folder when ``needs_archive``, else None. A module-level function (the workers import it by name).
    metrics : callable
        ``metrics(settings) -> column names`` of the metrics ``task`` returns (SI; the unit ends the name).
    check_name : callable
        ``check_name(name, table)`` raises :class:`SweepSpecError` if ``[grid]``/``[random]`` may not set ``name``.
    check_settings : callable, optional
        ``check_settings(settings, swept)`` raises :class:`SweepSpecError` (message from ``[run]`` on) on bad settings,
        or on settings that have no effect given the ``swept`` names.
    needs_archive : bool
        ``settings["structure"]`` names an SSP archive, sent to every worker once.
    run_time : callable, optional
        ``run_time(settings) -> seconds or None``: the time one run simulates, if the kind knows it (a sweep's
        :meth:`SweepSpec.length`).
    file_in : callable, optional
        ``file_in(name, value) -> (prefix, path) or None``: the file a setting's or a parameter's string value names
        (``value == prefix + path``), or None when it names none.
    """

    name: str
    settings: Mapping[str, object]
    task: Callable[[RunSpec, Path | None], dict]
    metrics: Callable[[dict], tuple[str, ...]]
    check_name: Callable[[str, str], None]
    check_settings: Callable[[dict, list[str]], None] | None = None
    needs_archive: bool = False
    run_time: Callable[[dict], float | None] | None = None
    file_in: Callable[[str, object], tuple[str, str] | None] | None = None


def sweepable(*names: str) -> Callable[[str, str], None]:
    """A ``check_name`` that allows exactly ``names``."""
    def check(name: str, table: str) -> None:
        if name not in names:
            raise SweepSpecError(f"[{table}] {name!r} cannot be swept; allowed: {', '.join(names)}")
    return check


def check_number(settings: dict, key: str, *, positive: bool = True, optional: bool = False) -> None:
    """Raise :class:`SweepSpecError` unless ``settings[key]`` is a finite (positive) number (or None if optional)."""
    value = settings[key]
    if value is None and optional:
        return
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value) or (
            positive and value <= 0):
        raise SweepSpecError(f"[run] {key} = {value!r}; must be a {'positive ' if positive else ''}number")


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A parsed spec: the run kind and settings, the grid, the random draws, where it came from, and the files its
    values name: ``files[(name, value)] = (prefix, resolved path)``."""

    name: str
    kind: SweepKind
    settings: dict
    grid: dict
    random: dict
    draws: int
    seed: int | None
    base_dir: Path
    files: dict = dataclasses.field(default_factory=dict)

    @property
    def swept_names(self) -> list[str]:
        """The parameter names that vary, grid first, in spec order."""
        return list(self.grid) + list(self.random)

    @property
    def run_count(self) -> int:
        """How many runs the spec expands to (without expanding it)."""
        return math.prod(len(values) for values in self.grid.values()) * self.draws

    def length(self) -> tuple[int, float | None]:
        """(runs, time they simulate in all [s], or None where the kind does not know a run's)."""
        each = self.kind.run_time(self.settings) if self.kind.run_time is not None else None
        return self.run_count, None if each is None else self.run_count * each

    def runs(self) -> list[RunSpec]:
        """Every run: the grid's combinations (in order) times the random draws."""
        return expand(self)


def canonical_json(data: object) -> str:
    """Sorted keys, no spaces, floats by ``repr``: the same text for the same values everywhere."""
    return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)


def run_id(kind: str, settings: dict, parameters: dict) -> str:
    """16 hex digits of the sha256 of the run's canonical JSON (kind, settings, parameters)."""
    text = canonical_json({"kind": kind, "settings": settings, "parameters": parameters})
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def load_spec(path: str | os.PathLike, kinds: Mapping[str, SweepKind]) -> SweepSpec:
    """Read and check a sweep spec of one of ``kinds`` from a TOML file (paths in it are relative to the file)."""
    path = Path(path)
    if path.exists() and not path.is_file():  # a folder, or a device such as /dev/zero that never ends
        raise SweepSpecError(f"{path}: not a regular file; a sweep spec is a TOML file")
    if path.is_file() and path.stat().st_size > MAX_SPEC_BYTES:
        raise SweepSpecError(f"{path}: {path.stat().st_size / 2**20:,.0f} MiB; a sweep spec is at most "
                             f"{MAX_SPEC_BYTES >> 20} MiB of TOML")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise SweepSpecError(f"{path}: cannot read the sweep spec ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise SweepSpecError(f"{path}: not a text file; a sweep spec is TOML (UTF-8)") from None
    except tomllib.TOMLDecodeError as exc:
        raise SweepSpecError(f"{path}: not valid TOML: {exc}") from None
    return parse_spec(data, kinds, base_dir=path.parent, source=str(path))


def parse_spec(data: dict, kinds: Mapping[str, SweepKind], *, base_dir: str | os.PathLike = ".",
               source: str = "spec") -> SweepSpec:
    """Check a spec of one of ``kinds`` given as a (TOML-decoded) mapping; see the module docstring."""
    unknown = set(data) - {"sweep", "run", "grid", "random"}
    if unknown:
        raise SweepSpecError(f"{source}: unknown table(s) {sorted(unknown)}; allowed: sweep, run, grid, random")
    sweep = _table(data.get("sweep", {}), "sweep", source)
    bad = set(sweep) - {"name"}
    if bad:
        raise SweepSpecError(f"{source}: [sweep] has unknown key(s) {sorted(bad)}; allowed: name")
    run = dict(_table(data.get("run"), "run", source, required=True))
    name = run.pop("kind", None)
    if name not in kinds:
        raise SweepSpecError(f"{source}: [run] kind = {name!r}; allowed: {', '.join(kinds)}")
    kind = kinds[name]
    bad = set(run) - set(kind.settings)
    if bad:
        raise SweepSpecError(f"{source}: [run] has unknown key(s) {sorted(bad)} for kind {name!r}; "
                             f"allowed: {', '.join(sorted(kind.settings))}")
    settings = {**kind.settings, **run}
    grid_table = _table(data.get("grid", {}), "grid", source)
    random_table = dict(_table(data.get("random", {}), "random", source))
    swept_names = list(grid_table) + [key for key in random_table if key not in ("draws", "seed")]
    try:  # the kind's own checks: their messages start at the table
        if kind.check_settings is not None:
            kind.check_settings(settings, swept_names)
        for table, names in (("grid", grid_table), ("random", set(random_table) - {"draws", "seed"})):
            for swept in names:
                kind.check_name(swept, table)
    except SweepSpecError as exc:
        raise SweepSpecError(f"{source}: {exc}") from None
    grid = _parse_grid(grid_table, source)
    draws = random_table.pop("draws", None)
    seed = random_table.pop("seed", None)
    random = {name: _parse_distribution(name, value, source) for name, value in random_table.items()}
    for name in random:
        if name in grid:
            raise SweepSpecError(f"{source}: {name!r} is in both [grid] and [random]")
    if random:
        if not isinstance(draws, int) or isinstance(draws, bool) or draws < 1:
            raise SweepSpecError(f"{source}: [random] draws = {draws!r}; must be a whole number >= 1")
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise SweepSpecError(f"{source}: [random] seed = {seed!r}; must be a whole number >= 0 (runs are seeded)")
    elif draws is not None or seed is not None:
        raise SweepSpecError(f"{source}: [random] has draws/seed but no distributions")
    if not grid and not random:
        raise SweepSpecError(f"{source}: nothing to sweep; give a [grid] (name = [values]) or a [random] table")
    name = _checked_name(sweep.get("name", Path(source).stem), source)
    files = _files(kind, settings, grid, Path(base_dir), source)
    spec = SweepSpec(name, kind, settings, grid, random, int(draws or 1), seed, Path(base_dir), files)
    if spec.run_count > MAX_RUNS:
        raise SweepSpecError(f"{source}: the spec expands to {spec.run_count:,} runs; at most {MAX_RUNS:,} (fewer grid "
                             "values or draws, or several specs)")
    return spec


#: The most runs a spec may expand to (a grid of 10 values in each of 5 parameters is 100 000).
MAX_RUNS = 100_000
#: Largest file a spec's value may name: it is shipped to every worker.
MAX_FILE_BYTES = 64 << 20


def string_values(table: dict):
    """(key, value) of every string value in ``table``, nested tables included (under their own keys)."""
    for key, value in table.items():
        if isinstance(value, dict):
            yield from string_values(value)
        elif isinstance(value, str):
            yield key, value


def map_strings(table: dict, change: Callable[[str, str], str]) -> dict:
    """``table`` with every string value (nested tables included) replaced by ``change(key, value)``."""
    return {key: map_strings(value, change) if isinstance(value, dict) else change(key, value) if isinstance(value, str)
            else value for key, value in table.items()}


def _files(kind: SweepKind, settings: dict, grid: dict, base_dir: Path, source: str) -> dict:
    """The files the settings' and the grid's values name (the kind's ``file_in``), resolved from ``base_dir``."""
    if kind.file_in is None:
        return {}
    values = [*string_values(settings),
              *((name, v) for name, values in grid.items() for v in values if isinstance(v, str))]
    files = {}
    for name, value in values:
        named = kind.file_in(name, value)
        if named is None:
            continue
        prefix, text = named
        path = base_dir / text  # an absolute path stays as it is
        if not path.is_file():
            raise SweepSpecError(f"{source}: {name} = {value!r}: no file {path} (a path in a spec is relative to the "
                                 "spec's folder)")
        if path.stat().st_size > MAX_FILE_BYTES:
            raise SweepSpecError(f"{source}: {name} = {value!r}: {path} is {path.stat().st_size / 2**20:,.0f} MiB; a "
                                 f"file shipped to every worker is at most {MAX_FILE_BYTES >> 20} MiB")
        files[(name, value)] = (prefix, path)
    return files


def _checked_name(name: object, source: str) -> str:
    """The sweep's name names its default folder runs/sweep-NAME: one plain folder name, nothing that leaves runs/."""
    text = str(name)
    if not text.strip() or text in (".", "..") or any(c in text for c in "/\\\0") or Path(text).is_absolute():
        raise SweepSpecError(f"{source}: [sweep] name = {name!r}; must be a plain folder name (no '/', '\\', "
                             "'..' or empty name)")
    return text


def _table(value, name: str, source: str, required: bool = False) -> dict:
    if value is None and required:
        raise SweepSpecError(f"{source}: missing the [{name}] table")
    if not isinstance(value, dict):
        raise SweepSpecError(f"{source}: [{name}] must be a table, not {type(value).__name__}")
    return value


def _parse_grid(grid: dict, source: str) -> dict:
    out = {}
    for name, values in grid.items():
        if not isinstance(values, list) or not values:
            raise SweepSpecError(f"{source}: [grid] {name} = {values!r}; must be a non-empty list of values")
        for value in values:
            if isinstance(value, float) and not math.isfinite(value):
                raise SweepSpecError(f"{source}: [grid] {name} has a non-finite value {value!r}")
            if not isinstance(value, (int, float, str, bool, list)):
                raise SweepSpecError(f"{source}: [grid] {name} has a value {value!r} that is not a number, "
                                     "string or Boolean")
        out[name] = list(values)
    return out


def _parse_distribution(name: str, value, source: str) -> dict:
    if not isinstance(value, dict):
        raise SweepSpecError(f"{source}: [random] {name} = {value!r}; must be {{distribution = ..., ...}}")
    distribution = value.get("distribution")
    if distribution not in DISTRIBUTIONS:
        raise SweepSpecError(f"{source}: [random] {name}: distribution = {distribution!r}; allowed: "
                             f"{', '.join(DISTRIBUTIONS)}")
    needed = DISTRIBUTIONS[distribution]
    keys = set(value) - {"distribution"}
    if keys != set(needed):
        raise SweepSpecError(f"{source}: [random] {name}: a {distribution} distribution takes exactly "
                             f"{', '.join(needed)} (got {', '.join(sorted(keys)) or 'nothing'})")
    a, b = (value[k] for k in needed)
    for key, number in zip(needed, (a, b)):
        if not isinstance(number, (int, float)) or isinstance(number, bool) or not math.isfinite(number):
            raise SweepSpecError(f"{source}: [random] {name}: {key} = {number!r}; must be a finite number")
    if distribution == "normal" and not b > 0:
        raise SweepSpecError(f"{source}: [random] {name}: std = {b!r}; must be > 0")
    if distribution in ("uniform", "loguniform", "integers") and not a < b:
        raise SweepSpecError(f"{source}: [random] {name}: low = {a!r} must be below high = {b!r}")
    if distribution == "loguniform" and not a > 0:
        raise SweepSpecError(f"{source}: [random] {name}: low = {a!r}; a loguniform distribution needs low > 0")
    if distribution == "integers" and not (isinstance(a, int) and isinstance(b, int)):
        raise SweepSpecError(f"{source}: [random] {name}: integers need whole-number low and high")
    return {"distribution": distribution, **{k: value[k] for k in needed}}


def draw(random: dict, draws: int, seed: int) -> list[dict]:
    """``draws`` samples of every distribution (names in spec order), from ``default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    columns = {}
    for name, d in random.items():
        kind = d["distribution"]
        if kind == "uniform":
            values = rng.uniform(d["low"], d["high"], draws)
        elif kind == "loguniform":
            values = np.exp(rng.uniform(math.log(d["low"]), math.log(d["high"]), draws))
        elif kind == "normal":
            values = rng.normal(d["mean"], d["std"], draws)
        else:
            values = rng.integers(d["low"], d["high"], draws, endpoint=True)
        columns[name] = [v.item() for v in values]
    return [{name: columns[name][i] for name in random} for i in range(draws)]


def expand(spec: SweepSpec) -> list[RunSpec]:
    """The runs of ``spec``: every grid combination with every random draw, each with its stable id."""
    names = list(spec.grid)
    points = [dict(zip(names, combo)) for combo in itertools.product(*(spec.grid[n] for n in names))]
    samples = draw(spec.random, spec.draws, spec.seed) if spec.random else [{}]
    runs = []
    seen = set()
    for point in points:
        for sample in samples:
            parameters = {**point, **sample}
            rid = run_id(spec.kind.name, spec.settings, parameters)
            if rid in seen:
                raise SweepSpecError(f"the spec gives the same run twice: {canonical_json(parameters)}")
            seen.add(rid)
            runs.append(RunSpec(rid, len(runs), parameters, spec.settings))
    return runs
