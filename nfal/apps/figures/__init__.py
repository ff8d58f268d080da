"""Figures a person looks at: one module per command group. A figure is drawn on a matplotlib ``Figure``
(no pyplot: no global state, no display), returned for a test to inspect, and written by :func:`save`."""

from __future__ import annotations


def save(figure, path) -> None:
    """Write ``figure`` to ``path`` (the format by its extension)."""
    figure.savefig(path, dpi=130)
