import pytest

from sim.sumo import sumo_missing


@pytest.fixture(scope="session")
def need_sumo() -> None:
    """Skip, saying how to install it, where SUMO is not installed."""
    why = sumo_missing()
    if why is not None:
        pytest.skip(f"needs Eclipse SUMO: {why}")
