import pytest

from protocol.corridor import load_corridor
from sim.render.renderer import Renderer


@pytest.fixture(scope="session")
def corridor():
    return load_corridor()


@pytest.fixture(scope="session")
def clean_renderer(corridor):
    """rsu1's renderer without noise, blur, exposure drift or cast shadows: the pixels that change when a
    vehicle is removed are the vehicle's own."""
    return Renderer(corridor.rsu("rsu1").camera, corridor.road, seed=3, noise=False, motion_blur=False, exposure=False,
                    shadows=False)
