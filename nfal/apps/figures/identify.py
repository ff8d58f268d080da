"""The figure of ``nfal identify``: equilibria and K fit (Fig. 4's analogue), the damping factors, and the
measured step responses against eq. (13) before and after the damping correction (Fig. 6's analogue)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.gridspec import GridSpec  # noqa: E402

from nfal.apps.rig_analysis import Identification  # noqa: E402
from nfal.models.calibration import paper_calibration  # noqa: E402
from nfal.models.identification import simulate_step  # noqa: E402
from nfal.models.plant import SimplifiedPlant  # noqa: E402
from nfal.models.rig import RigParameters  # noqa: E402

STEP_COLUMNS = 4


def plot_identification(path, result: Identification, rig: RigParameters, lag_s: float) -> None:
    """Write the identification figure to ``path`` (PNG)."""
    rows = -(-len(result.steps) // STEP_COLUMNS)
    figure = plt.figure(figsize=(15, 4.2 + 2.6 * rows))
    grid = GridSpec(1 + rows, 12, figure=figure, height_ratios=[1.5] + [1] * rows)
    _plot_K(figure.add_subplot(grid[0, 0:4]), result)
    _plot_equilibria(figure.add_subplot(grid[0, 4:8]), result, rig)
    _plot_damping(figure.add_subplot(grid[0, 8:12]), result)
    for i, steps in enumerate(result.steps):
        axis = figure.add_subplot(grid[1 + i // STEP_COLUMNS, 3 * (i % STEP_COLUMNS):3 * (i % STEP_COLUMNS) + 3])
        _plot_step(axis, steps[1], result, rig, lag_s, legend=i == 0)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _plot_K(axis, result: Identification) -> None:
    calibration = result.calibration
    sigma = np.linspace(calibration.sigma.min(), calibration.sigma.max(), 200)
    axis.plot(calibration.sigma, calibration.measured_K, "o", color="black", ms=4, label="measured, eq. (16)")
    axis.plot(sigma, calibration.fit(sigma), "-", color="tab:blue", label="fit, form of eq. (17)")
    axis.plot(sigma, paper_calibration()(sigma), ":", color="grey", label="paper's eq. (17)")
    axis.set_xlabel("squeeze number σ [-]")
    axis.set_ylabel("K(σ) [-]")
    axis.set_title("(a) K(σ) from the equilibria (Fig. 4)")
    axis.legend(fontsize=8)


def _plot_equilibria(axis, result: Identification, rig: RigParameters) -> None:
    voltage = np.array([p.voltage for p in result.equilibria])
    height = np.array([p.height for p in result.equilibria])
    spread = np.array([p.spread for p in result.equilibria])
    model = SimplifiedPlant(rig, result.calibration.fit)
    heights = np.linspace(height.min(), height.max(), 100)
    axis.errorbar(voltage, height * 1e6, yerr=2 * spread * 1e6, fmt="o", color="black", ms=4, capsize=2,
                  label="measured mean ± 2 std")
    axis.plot(model.equilibrium_excitation(heights) / result.metres_per_volt, heights * 1e6, "-", color="tab:blue",
              label="identified model, eq. (16)")
    axis.set_xlabel("drive voltage [V]")
    axis.set_ylabel("equilibrium height [µm]")
    axis.set_title("(b) equilibria at constant drive")
    axis.legend(fontsize=8)


def _plot_damping(axis, result: Identification) -> None:
    table = result.damping
    heights = np.linspace(table.heights_m[0], table.heights_m[-1], 200)
    for fits in result.step_fits:
        axis.plot([f.height * 1e6 for f in fits], [f.factor for f in fits], ".", color="grey", ms=3)
    axis.errorbar(table.heights_m * 1e6, table.factors, yerr=[table.factors - table.factors_low,
                  table.factors_high - table.factors], fmt="o", color="black", ms=4, capsize=3,
                  label="mean, 95 % interval")
    axis.plot(heights * 1e6, table.factor(heights), "-", color="tab:blue", label="PCHIP on log factor")
    axis.axhline(1.0, color="tab:orange", ls="--", lw=1, label="eq. (6)")
    axis.set_yscale("log")
    axis.set_xlabel("height [µm]")
    axis.set_ylabel("damping / eq. (6) [-]")
    axis.set_title("(c) damping factor (grey: each step)")
    axis.legend(fontsize=8)


def _plot_step(axis, step, result: Identification, rig: RigParameters, lag_s: float, legend: bool) -> None:
    model = SimplifiedPlant(rig, result.calibration.fit)
    a1, a2 = step.voltage_before * result.metres_per_volt, step.voltage_after * result.metres_per_volt
    start = model.equilibrium_height(a1)
    times = step.times[step.times >= 0]
    axis.plot(step.times * 1e3, step.heights * 1e6, "-", color="black", lw=0.8, label="measured")
    for factor, style, label in ((lambda h: 1.0, "--", "eq. (13) with eq. (6)"),
                                 (result.damping.factor, "-", "with the damping correction")):
        simulated = simulate_step(times, start, a1, a2, rig, result.calibration.fit, factor, lag_s)
        axis.plot(np.concatenate([[step.times[0], 0.0], times]) * 1e3,
                  np.concatenate([[start, start], simulated]) * 1e6,
                  style, color="tab:orange" if style == "--" else "tab:blue", lw=1.4, label=label)
    axis.set_title(f"near {start * 1e6:.0f} µm: drive {step.voltage_before:.3g} → {step.voltage_after:.3g} V",
                   fontsize=9)
    axis.set_xlabel("time [ms]", fontsize=8)
    axis.set_ylabel("height [µm]", fontsize=8)
    axis.tick_params(labelsize=7)
    if legend:
        axis.legend(fontsize=7, loc="upper right")
