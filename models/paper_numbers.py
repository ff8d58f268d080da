"""The paper's published numbers and claims (``data/paper_numbers.json``), each with where it stands in the paper.

One file holds them, so each is typed once: eq. (17)'s coefficients and Table 1 are read from it here, and
``nfal reproduce`` sets every number it measures beside the paper's.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from importlib import resources

_FILE = resources.files(__package__) / "data" / "paper_numbers.json"


@dataclasses.dataclass(frozen=True)
class PaperNumber:
    """One published value: ``value`` in ``unit`` (SI; "%" for percentages, "" for a claim that holds or not),
    ``relation`` "=" (a value), "<" (a bound), "~" (an approximate value); ``where`` in the paper, ``what`` it is,
    and the paper's wording (``quote``) where it is a statement rather than a number."""

    id: str
    value: float | bool
    unit: str
    where: str
    what: str
    relation: str = "="
    quote: str = ""


@functools.cache
def paper_numbers() -> dict[str, PaperNumber]:
    """Every number of the data file, by id."""
    entries = json.loads(_FILE.read_text(encoding="utf-8"))["numbers"]
    return {entry["id"]: PaperNumber(**entry) for entry in entries}


def paper_value(key: str) -> float | bool:
    """The value of the number ``key`` (e.g. ``"table1.a.delta"``)."""
    return paper_numbers()[key].value
