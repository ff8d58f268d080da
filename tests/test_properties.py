"""The property tests' number of examples (tests/helpers/properties.py): their own in the full suite, a fifth on the
fast path."""

from helpers import properties


def test_the_fast_path_draws_a_fifth_of_the_examples_and_the_full_suite_all(request, monkeypatch):
    fast = "not slow" in (request.config.option.markexpr or "")
    assert properties.fast_path is fast  # as this session was started
    monkeypatch.setattr(properties, "fast_path", False)
    assert properties.examples(250).max_examples == 250 and properties.examples(40).deadline is None
    monkeypatch.setattr(properties, "fast_path", True)
    assert (properties.examples(250).max_examples, properties.examples(60).max_examples) == (50, 20)
