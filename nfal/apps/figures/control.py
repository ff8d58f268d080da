"""Figures of the control commands: the stability map (Fig. 8) and the closed-loop comparison (Figs. 9-10)."""

from __future__ import annotations

import matplotlib
import numpy as np
from matplotlib import colors, ticker
from matplotlib.figure import Figure

from nfal.apps.figures import save

#: Fig. 8's colours: green below |z| = 1 (stable), red above; the two halves meet at |z| = 1.
STABILITY_COLOURS = "RdYlGn_r"


def plot_stability_map(path, grid) -> None:
    """Write :func:`stability_map_figure` to ``path``."""
    save(stability_map_figure(grid), path)


def stability_map_figure(grid) -> Figure:
    """Fig. 8: max |z| over (operating height, design height), with the |z| = 1 contour and the diagonal."""
    design, operating = grid.design_height_m * 1e6, grid.operating_height_m * 1e6
    moduli = grid.max_pole_modulus
    figure = Figure(figsize=(7.2, 5.6), layout="constrained")
    axis = figure.subplots()
    low, high = float(moduli.min()), float(moduli.max())
    cmap, norm, ticks = _stability_colours(low, high)
    mesh = axis.pcolormesh(operating, design, moduli, shading="nearest", cmap=cmap, norm=norm)
    bar = figure.colorbar(mesh, ax=axis, ticks=ticks, format="%g")
    bar.set_label("max |z| of the discrete closed loop [-]")
    if low < 1.0 < high:
        contour = axis.contour(operating, design, moduli, levels=[1.0], colors="black", linewidths=1.5)
        axis.clabel(contour, fmt="|z| = 1", fontsize=8)
    stable = moduli < 1.0
    if stable.any():
        levels = np.quantile(moduli[stable], [0.25, 0.5, 0.75])
        lines = axis.contour(operating, design, np.where(stable, moduli, np.nan), levels=np.unique(levels),
                             colors="grey", linewidths=0.7)
        axis.clabel(lines, fmt="%.3f", fontsize=7)
    span = [max(design.min(), operating.min()), min(design.max(), operating.max())]
    axis.plot(span, span, "--", color="navy", lw=1, label="design = operating (gain scheduling)")
    axis.set_xlabel("operating height (actual clearance) [µm]")
    axis.set_ylabel("design height [µm]")
    method = {"forward_euler": "forward Euler",
              "zoh": "ZOH plant, forward-Euler controller"}.get(grid.discretisation, grid.discretisation)
    axis.set_title(f"Fig. 8: closed-loop pole nearest |z| = 1, {grid.placement} placement\n"
                   f"({method}, {grid.sample_rate_hz:g} Hz)", fontsize=10)
    axis.legend(loc="lower right", fontsize=8)
    return figure


def _stability_colours(low: float, high: float):
    """(colour map, norm, colour-bar ticks) for max |z| from ``low`` to ``high``.

    Each side of |z| = 1 gets half the bar and its own ticks: the stable side spans hundredths, the unstable
    one up to tens, and one set of ticks over both leaves the stable half bare. A map on one side of 1 takes
    that half of the colours alone.
    """
    full = matplotlib.colormaps[STABILITY_COLOURS]
    stable = [t for t in ticker.MaxNLocator(5).tick_values(low, 1.0) if low <= t <= 1.0]
    unstable = [t for t in ticker.MaxNLocator(4).tick_values(1.0, high) if 1.0 < t <= high]
    if high <= 1.0:
        return _half(full, 0.0), colors.Normalize(min(low, 0.999), 1.0), stable
    if low >= 1.0:
        return _half(full, 0.5), colors.Normalize(1.0, max(high, 1.001)), [1.0, *unstable]
    return full, colors.TwoSlopeNorm(vcenter=1.0, vmin=low, vmax=high), stable + unstable


def _half(cmap, start: float):
    """The half of ``cmap`` from ``start`` (0 or 0.5)."""
    return colors.ListedColormap(cmap(np.linspace(start, start + 0.5, 128)), name=f"{cmap.name}_{start:g}")


def plot_comparison(path, runs: dict, **labels) -> None:
    """Write :func:`comparison_figure` to ``path``."""
    save(comparison_figure(runs, **labels), path)


def comparison_figure(runs: dict, *, title: str = "Closed-loop responses to the reference (Figs. 9-10 analogue)",
                      height_label: str = "clearance") -> Figure:
    """Figs. 9-10: per controller, its clearance against the reference over the run (left) and, zoomed on the
    second half of the highest level's last hold, with the measured height (right): the sensor's 2 um of noise
    is a pixel or two on the full range's scale, hidden under the clearance's line."""
    figure = Figure(figsize=(11, 2.3 * len(runs) + 0.9), layout="constrained")
    axes = figure.subplots(len(runs), 2, sharex="col", sharey="col", squeeze=False, width_ratios=(3, 1))
    for (full, zoom), (key, run) in zip(axes, runs.items()):
        colour = "tab:blue" if key == "gs" else "tab:orange"
        label = f"{height_label}: {'gain-scheduled' if key == 'gs' else 'linear'}"  # the legend tells the colours
        full.plot(run.time_s, run.height_m * 1e6, color=colour, lw=1.2, label=label)
        full.step(run.time_s, run.reference_m * 1e6, where="post", color="black", ls="--", lw=1, label="reference")
        full.set_ylabel("clearance [µm]")
        full.set_title(run.controller if key == "gs" else f"linear controller designed at {key} µm", fontsize=10)
        low, high = run.reference_m.min() * 1e6, run.reference_m.max() * 1e6
        full.set_ylim(low - 0.35 * (high - low), high + 0.35 * (high - low))
        window = _top_hold_tail(run.reference_m)
        if not np.array_equal(run.measured_m, run.height_m):  # on a rig the measured height is the clearance
            zoom.plot(run.time_s[window], run.measured_m[window] * 1e6, color="0.5", lw=0.8, zorder=1,
                      label="measured (with noise)")
        zoom.plot(run.time_s[window], run.height_m[window] * 1e6, color=colour, lw=1.2, zorder=2, label=label)
        zoom.step(run.time_s[window], run.reference_m[window] * 1e6, where="post", color="black", ls="--", lw=1,
                  zorder=3, label="reference")
        for axis in (full, zoom):
            axis.grid(alpha=0.3)
    top_level = max(run.reference_m.max() for run in runs.values())
    axes[0, 1].set_title(f"zoom: end of the {top_level * 1e6:g} µm hold", fontsize=10)
    handles = {line.get_label(): line for row in axes for line in (*row[1].get_lines(), *row[0].get_lines())}
    figure.legend(handles.values(), handles.keys(), loc="outside lower center", ncol=len(handles), fontsize=8)
    for axis in axes[-1]:
        axis.set_xlabel("time [s]")
    figure.suptitle(title, fontsize=11)
    return figure


def _top_hold_tail(reference_m: np.ndarray) -> slice:
    """The samples of the second half of the last hold at the reference's highest level."""
    top = reference_m >= reference_m.max()
    starts = np.flatnonzero(top & ~np.r_[False, top[:-1]])
    end = np.flatnonzero(top)[-1] + 1
    return slice((starts[-1] + end) // 2, end)
