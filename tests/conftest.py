import matplotlib

matplotlib.use("Agg")


import pytest  # noqa: E402


@pytest.fixture(scope="session")
def fig7_archives(tmp_path_factory):
    """The FMUs built and both Fig. 7 structures packed once per test session: {name: .ssp path}."""
    from nfal.build import build_all

    return build_all(tmp_path_factory.mktemp("fig7_build"))
