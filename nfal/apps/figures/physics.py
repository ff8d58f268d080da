"""Figures of the physics commands: K(sigma) (Fig. 4), an experimental fit, Table 1 responses (Fig. 5)."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from nfal.apps.figures import save


def plot_calibration(path, sigma, K, label: str, reference=None) -> None:
    """Write :func:`calibration_figure` to ``path``."""
    save(calibration_figure(sigma, K, label, reference), path)


def calibration_figure(sigma, K, label: str, reference=None) -> Figure:
    """K(sigma) as in Fig. 4; with ``reference`` (eq. 17) its curve and the difference are shown too. The
    legend sits under the axes: inside, K's dip below zero and the difference's fall leave it no free corner."""
    figure = Figure(figsize=(7, 5.2), layout="constrained")
    axis = figure.subplots()
    axis.plot(sigma, K, "o-", ms=3, color="tab:blue", label=f"numerical ({label})")
    if reference is not None:
        low, high = reference.sigma_range
        inside = (sigma >= low) & (sigma <= high)
        if inside.any():
            fine = np.linspace(max(low, sigma.min()), min(high, sigma.max()), 300)
            axis.plot(fine, reference(fine), "-", color="black", label=f"measured fit, {reference.name}")
            axis.plot(sigma[inside], reference(sigma[inside]) - K[inside], "--", color="tab:orange",
                      label="difference (measured - numerical)")
    axis.axhline(0.0, color="grey", lw=0.6)
    axis.set_xlabel("squeeze number σ [-]")
    axis.set_ylabel("calibration function K(σ) [-]")
    axis.set_title("Calibration function K(σ), eq. (12)")
    axis.grid(alpha=0.3)
    figure.legend(loc="outside lower center", ncol=2, fontsize=9)
    return figure


def plot_experimental_fit(path, result, reference=None) -> None:
    """Measured K points, the fitted polynomial and its residuals."""
    figure = Figure(figsize=(7, 6), layout="constrained")
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=(3, 1))
    sigma = np.linspace(*result.fit.sigma_range, 300)
    top.plot(result.sigma, result.measured_K, "o", ms=4, label="from measured equilibria, eq. (16)/(18)")
    top.plot(sigma, result.fit(sigma), "-", label=f"fit, degree {result.fit.coefficients.size - 1}")
    if reference is not None:
        top.plot(sigma, reference(sigma), ":", color="black", label=reference.name)
    top.set_ylabel("K(σ) [-]")
    top.set_title("Experiment-based calibration (Sec. 3.2.2)")
    top.grid(alpha=0.3)
    top.legend()
    bottom.plot(result.sigma, result.residuals, "o", ms=4, color="tab:red")
    bottom.axhline(0.0, color="grey", lw=0.6)
    bottom.set_xlabel("squeeze number σ [-]")
    bottom.set_ylabel("residual [-]")
    bottom.grid(alpha=0.3)
    save(figure, path)


def plot_table1(path, results) -> None:
    """Fig. 5: release from rest, full model (solid black) vs simplified model (dashed orange), per case."""
    columns = min(2, len(results))
    rows = int(np.ceil(len(results) / columns))
    figure = Figure(figsize=(6 * columns, 3.6 * rows), layout="constrained")
    axes = figure.subplots(rows, columns, squeeze=False)
    for axis, result in zip(axes.flat, results):
        case = result.case
        axis.plot(result.time_full * 1e3, result.height_full * 1e6, "-", color="black", lw=1.6,
                  label="full model (3)-(5)")
        axis.plot(result.time_simplified * 1e3, result.height_simplified * 1e6, "--", color="tab:orange", lw=1.6,
                  label="simplified (13)")
        axis.set_title(f"({case.name}) m = {case.mass * 1e3:g} g, f = {case.frequency / 1e3:g} kHz, "
                       f"|a| = {case.excitation * 1e6:g} µm\n"
                       f"δ = {result.delta_full:.4f}, steady-state error {result.error_percent:.3f} %", fontsize=9)
        axis.set_xlabel("time [ms]")
        axis.set_ylabel("clearance h̄ [µm]")
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    for axis in list(axes.flat)[len(results):]:
        axis.set_visible(False)
    save(figure, path)
