"""The figures the commands write, as a reader sees them: checked on the matplotlib Figure (panels, artists,
ticks), not on pixels."""

import numpy as np
import pytest

from nfal.figures.control import stability_map_figure
from nfal.models.stability import StabilityMap


def _stability_map(low: float, high: float) -> StabilityMap:
    heights = np.linspace(50e-6, 200e-6, 7)
    moduli = np.geomspace(low, high, heights.size ** 2).reshape(heights.size, heights.size)
    return StabilityMap(heights, heights, moduli, "forward_euler", 2000.0)


@pytest.mark.parametrize("low, high", [(0.951, 14.8), (0.956, 0.9967), (1.2, 3.0)],
                         ids=["both sides of 1 (the paper's Fig. 8)", "all stable (sampled)", "all unstable"])
def test_stability_map_colour_bar_ticks_both_sides_of_one(low, high):
    figure = stability_map_figure(_stability_map(low, high))
    bar = figure.axes[1]
    ticks = np.asarray(bar.get_yticks())
    bottom, top = bar.get_ylim()
    shown = ticks[(ticks >= bottom) & (ticks <= top)]
    assert shown.size == ticks.size and bottom <= low and high <= top
    if low < 1.0:
        assert np.count_nonzero(shown < 1.0) >= 3, shown  # the stable range that matters has its own ticks
    if high > 1.0:
        assert np.count_nonzero(shown > 1.0) >= 2, shown
    if low < 1.0 < high:
        assert 1.0 in shown
