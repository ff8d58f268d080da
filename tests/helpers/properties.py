"""How hard a property test tries: its own number of examples in the full suite, a fifth of it (at least 20) on the
fast path (``-m "not slow"``), which tests/conftest.py says before the test modules are imported. Drawing the examples
is most of these tests' time (tests/test_hil_protocol.py: hypothesis' draws, not the decoder)."""

from __future__ import annotations

from hypothesis import settings

#: Set by tests/conftest.py: the session deselects the slow tests.
fast_path = False


def examples(count: int, **options) -> settings:
    """Hypothesis settings of ``count`` examples (a fifth on the fast path), with no deadline."""
    return settings(max_examples=max(20, count // 5) if fast_path else count, deadline=None, **options)
