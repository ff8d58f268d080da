"""``sweep.png``: a sweep's metrics over its swept parameters, one panel per metric and parameter."""

from __future__ import annotations

import math
from pathlib import Path

from .sweep_spec import SweepSpec

#: A metric's unit ends its name (SI, :func:`~nfal.orchestration.sweep.metric_columns`): name ending -> unit.
UNIT_SUFFIXES = (("_m_s", "m s"), ("_percent", "%"), ("_hz", "Hz"), ("_m", "m"), ("_s", "s"))
#: Units shown with an SI prefix on the ticks (1.7 µm s, 30 ms).
PREFIXED_UNITS = ("m s", "Hz", "m", "s")


def plot_sweep(spec: SweepSpec, rows: list[dict], metrics: list[str], path: Path) -> Path | None:
    """Write :func:`sweep_figure` to ``path``; None (and no file) when it has nothing to show."""
    figure = sweep_figure(spec, rows, metrics)
    if figure is None:
        return None
    figure.savefig(path, dpi=110)
    return path


def sweep_figure(spec: SweepSpec, rows: list[dict], metrics: list[str]):
    """Each of ``metrics`` over each swept parameter whose value varies among the runs that finished ok.

    One such parameter: a panel per metric, the runs joined by a line over it. Several: a row per metric and
    a column per parameter, each run a dot, the mean over the other parameters joined where a value
    repeats, so that no parameter's effect hides as the scatter of another's. None: histograms. Numbers on
    the x axis, strings as categories; metric ticks in SI with a prefix (µm, ms). None when no run
    finished ok with a finite value of a metric.
    """
    from matplotlib.figure import Figure  # on use (0.3 s): plotting only; no pyplot, no global state

    ok = [r for r in rows if r["status"] == "ok"]
    metrics = [m for m in metrics if any(_finite(r.get(m)) for r in ok)]
    if not metrics:
        return None
    swept = [n for n in spec.swept_names if len({str(r.get(f"param:{n}")) for r in ok}) > 1]
    panels = [(m, p) for m in metrics for p in swept or [None]]
    columns = len(swept) if len(swept) > 1 else min(3, len(metrics))
    figure = Figure(figsize=(4.2 * columns, 3.1 * math.ceil(len(panels) / columns)), layout="constrained")
    axes = figure.subplots(math.ceil(len(panels) / columns), columns, squeeze=False)
    for axis, (metric, parameter) in zip(axes.flat, panels):
        _metric_panel(axis, ok, metric, parameter, joined=len(swept) == 1)
    for axis in list(axes.flat)[len(panels):]:
        axis.set_visible(False)
    failed = len(rows) - len(ok)
    figure.suptitle(f"{spec.name}: {len(ok)} runs" + (f", {failed} failed" if failed else "")
                    + ("\ndots: the runs; line: their mean over the other parameters" if len(swept) > 1 else ""))
    return figure


def _metric_panel(axis, rows: list[dict], metric: str, parameter: str | None, joined: bool) -> None:
    """``metric`` over ``parameter`` (its histogram when None); ``joined``: every run on one line."""
    from matplotlib.ticker import EngFormatter  # on use: plotting only

    name, unit = _name_and_unit(metric)
    points = [(r.get(f"param:{parameter}"), r[metric]) for r in rows if _finite(r.get(metric))]
    if unit in PREFIXED_UNITS:
        (axis.xaxis if parameter is None else axis.yaxis).set_major_formatter(EngFormatter(unit=unit))
    label = name if unit in PREFIXED_UNITS or unit is None else f"{name} [{unit}]"
    if parameter is None:
        axis.hist([y for _, y in points], bins=min(20, max(5, len(points) // 2)))
        axis.set_xlabel(label)
        axis.set_ylabel("runs")
        return
    if all(isinstance(x, float) for x, _ in points):
        position = {x: x for x, _ in points}
    else:
        categories = sorted({str(x) for x, _ in points})
        position = {x: categories.index(str(x)) for x, _ in points}
        axis.set_xticks(range(len(categories)), categories, rotation=30 if max(map(len, categories)) > 4 else 0,
                      fontsize=8)
        axis.margins(x=0.15)
    groups: dict = {}
    for x, y in points:
        groups.setdefault(position[x], []).append(y)
    axis.plot([position[x] for x, _ in points], [y for _, y in points], "o", color="tab:blue", alpha=0.7, ms=5)
    if joined or len(groups) < len(points):
        axis.plot(*zip(*sorted((x, sum(ys) / len(ys)) for x, ys in groups.items())), "-", color="tab:blue", lw=1)
    axis.set_xlabel(parameter)
    axis.set_ylabel(label)
    axis.grid(alpha=0.3)


def _name_and_unit(metric: str) -> tuple[str, str | None]:
    """('rise time', 's') for 'rise_time_s'; (the name, None) without a unit ending."""
    for suffix, unit in UNIT_SUFFIXES:
        if metric.endswith(suffix):
            return metric[:-len(suffix)].replace("_", " "), unit
    return metric.replace("_", " "), None


def _finite(value) -> bool:
    return isinstance(value, float) and math.isfinite(value)
