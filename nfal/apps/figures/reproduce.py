"""Figures and the HTML page of ``nfal reproduce``: Fig. 6 (constant excitations), Fig. 4 (K three ways), and the
report that sets every number beside the paper's."""

from __future__ import annotations

import html

import numpy as np
from matplotlib.figure import Figure

from nfal.apps.figures import save


def plot_constant_excitation(path, rig_run, model_run, steps) -> None:
    """Fig. 6: the emulated rig's measured height (and low-passed) and eq. (13)'s response, under constant
    excitations; the levels they should hold dashed."""
    figure = Figure(figsize=(10, 5), layout="constrained")
    axis = figure.subplots()
    axis.plot(rig_run.time_s, rig_run.measured_m * 1e6, color="0.75", lw=0.6, label="emulated rig, measured")
    axis.plot(rig_run.time_s, rig_run.height_m * 1e6, color="black", lw=1.4, label="emulated rig, low-passed 35 Hz")
    axis.plot(model_run.time_s, model_run.height_m * 1e6, "--", color="tab:orange", lw=1.4,
              label="eq. (13),(17), ideal steps of |a|")
    axis.step(rig_run.time_s, rig_run.reference_m * 1e6, where="post", color="tab:blue", lw=0.8, ls=":",
              label="equilibrium of each |a| by eq. (16)")
    axis.set_xlabel("time [s]")
    axis.set_ylabel("clearance [µm]")
    axis.set_title(f"Fig. 6 analogue: {len(steps.levels_m)} constant excitations (the first lifts off from rest)",
                   fontsize=10)
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8, loc="lower right")
    save(figure, path)


def plot_calibrations(path, sigma, numerical, measured, eq17) -> None:
    """Fig. 4: eq. (17), K from the measured equilibria with its quartic, the numerical K, and the differences of
    the two fits from eq. (17)."""
    figure = Figure(figsize=(8, 6.4), layout="constrained")
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=(3, 1.3))
    fine = np.linspace(*eq17.sigma_range, 400)
    top.plot(fine, eq17(fine), color="black", lw=1.6, label="eq. (17): the paper's fit to its measurements")
    top.plot(measured.sigma, measured.measured_K, "o", color="tab:red", ms=5, label="emulated rig: K by eq. (16)")
    span = np.linspace(*measured.fit.sigma_range, 200)
    top.plot(span, measured.fit(span), "--", color="tab:red", lw=1.2, label="emulated rig: quartic fit")
    top.plot(sigma, numerical, "-", color="tab:blue", lw=1.2, label="numerical (perturbation, Fig. 3 stand-in)")
    top.set_ylabel("K(σ) [-]")
    top.set_title("Fig. 4 analogue: K(σ) numerically and from measured equilibria", fontsize=10)
    top.grid(alpha=0.3)
    top.legend(fontsize=8)
    inside = (sigma >= eq17.sigma_range[0]) & (sigma <= eq17.sigma_range[1])
    bottom.plot(sigma[inside], eq17(sigma[inside]) - numerical[inside], color="tab:blue",
                label="eq. (17) - numerical")
    bottom.plot(span, eq17(span) - measured.fit(span), "--", color="tab:red", label="eq. (17) - rig's fit")
    bottom.axhline(0.0, color="grey", lw=0.6)
    bottom.set_xlabel("squeeze number σ [-]")
    bottom.set_ylabel("difference [-]")
    bottom.grid(alpha=0.3)
    bottom.legend(fontsize=8)
    save(figure, path)


def shown(value) -> str:
    """A number or a claim as the report shows it: 4 significant figures, yes or no, a dash for none."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return f"{value:.4g}"


#: The table cell's class of each verdict.
VERDICT_CLASS = {"holds": "ok", "differs": "differs", "known difference": "differs", "shown": "info"}


def write_html(path, report) -> None:
    """One page: per section what was run, its figure, and a table of our numbers beside the paper's."""
    quick = " (--quick: smaller grids)" if report.quick else ""
    parts = [f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>nfal reproduce: the paper's results</title>
<style>
body {{ font-family: sans-serif; max-width: 72em; margin: 2em auto; color: #222; }}
table {{ border-collapse: collapse; width: 100%; font-size: 0.9em; margin-bottom: 1em; }}
th, td {{ border: 1px solid #ccc; padding: 0.3em 0.5em; text-align: left; vertical-align: top; }}
th {{ background: #f3f3f3; }} .ok {{ background: #e3f6e3; }} .differs {{ background: #fbe3e3; }}
.info {{ background: #f3f3f3; }} img {{ max-width: 100%; border: 1px solid #ddd; }} .note {{ color: #555; }}
</style></head><body>
<h1>The paper's results, reproduced by nfal</h1>
<p>Ilssar, Bucher, Flashner: modelling and closed-loop control of near-field acoustically levitated objects.
{report.summary}{quick}.
Every number is also in <code>report.json</code>; the paper's are in
<code>models/data/paper_numbers.json</code> (<code>nfal/models/data/</code> where nfal is installed).</p>
"""]
    for section in report.sections:
        title = html.escape(section.title)
        parts.append(f"<h2>{title}</h2>\n<p>{html.escape(section.method)}</p>\n"
                     f'<p><img src="{html.escape(section.figure)}" alt="{title}"></p>\n'
                     "<table><tr><th>where</th><th>what</th><th>paper</th><th>ours</th><th>ours - paper</th>"
                     "<th>unit</th>"
                     "<th>tolerance</th><th>result</th><th>note</th></tr>\n")
        for c in section.comparisons:
            row = c.to_dict()
            why = f" Why: {row['known_difference']}" if c.verdict == "known difference" else ""
            quote = f'<br><i>"{html.escape(row["quote"])}"</i>' if row["quote"] else ""
            cells = [html.escape(row["where"]), html.escape(row["what"]) + quote, html.escape(c.paper_shown),
                     shown(c.ours), shown(c.difference), html.escape(c.unit), html.escape(row["tolerance"])]
            parts.append("<tr>" + "".join(f"<td>{cell}</td>" for cell in cells)
                         + f'<td class="{VERDICT_CLASS[c.verdict]}">{c.verdict}</td>'
                         + f'<td class="note">{html.escape(row["note"] + why)}</td></tr>\n')
        parts.append(f"</table><p class=\"note\">{section.seconds:.1f} s</p>\n")
    parts.append("</body></html>\n")
    path.write_text("".join(parts), encoding="utf-8")
