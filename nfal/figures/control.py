"""Figures of the control commands: the stability map (Fig. 8) and the closed-loop comparison (Figs. 9-10)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import colors  # noqa: E402


def _save(figure, path) -> None:
    figure.tight_layout()
    figure.savefig(path, dpi=130)
    plt.close(figure)


def plot_stability_map(path, grid) -> None:
    """Fig. 8: max |z| over (operating height, design height), with the |z| = 1 contour and the diagonal."""
    design, operating = grid.design_height_m * 1e6, grid.operating_height_m * 1e6
    moduli = grid.max_pole_modulus
    figure, axis = plt.subplots(figsize=(7.2, 5.6))
    low, high = float(moduli.min()), float(moduli.max())
    norm = colors.TwoSlopeNorm(vcenter=1.0, vmin=min(low, 0.999), vmax=max(high, 1.001))
    mesh = axis.pcolormesh(operating, design, moduli, shading="nearest", cmap="RdYlGn_r", norm=norm)
    bar = figure.colorbar(mesh, ax=axis)
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
    method = {"forward_euler": "forward Euler", "zoh": "ZOH plant, forward-Euler controller"}.get(grid.discretisation, grid.discretisation)
    axis.set_title(f"Fig. 8: closed-loop pole nearest |z| = 1, {grid.placement} placement\n"
                   f"({method}, {grid.sample_rate_hz:g} Hz)", fontsize=10)
    axis.legend(loc="lower right", fontsize=8)
    _save(figure, path)


def plot_comparison(path, runs: dict) -> None:
    """Figs. 9-10: each controller's clearance (true and measured) against the reference, one panel each."""
    figure, axes = plt.subplots(len(runs), 1, figsize=(8, 2.3 * len(runs) + 0.6), sharex=True, squeeze=False)
    for axis, (key, run) in zip(axes[:, 0], runs.items()):
        axis.plot(run.time_s, run.measured_m * 1e6, color="0.55", lw=0.4, alpha=0.7, label="measured (with noise)")
        axis.plot(run.time_s, run.height_m * 1e6, color="tab:blue" if key == "gs" else "tab:orange", lw=1.2,
                  label="clearance")
        axis.step(run.time_s, run.reference_m * 1e6, where="post", color="black", ls="--", lw=1, label="reference")
        axis.set_ylabel("clearance [µm]")
        axis.set_title(run.controller if key == "gs" else f"linear controller designed at {key} µm", fontsize=10)
        axis.grid(alpha=0.3)
        low, high = run.reference_m.min() * 1e6, run.reference_m.max() * 1e6
        axis.set_ylim(low - 0.35 * (high - low), high + 0.35 * (high - low))
    axes[0, 0].legend(loc="upper left", fontsize=8, ncol=3)
    axes[-1, 0].set_xlabel("time [s]")
    figure.suptitle("Closed-loop responses to the reference (Figs. 9-10 analogue)", fontsize=11)
    _save(figure, path)
