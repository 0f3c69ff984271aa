"""Fixtures of the vehicle tests."""

from __future__ import annotations

import pytest

from protocol.road import Road, Segment


@pytest.fixture
def road() -> Road:
    """A straight two-lane road, 1 km, lanes 3.7 m wide (lane 1 centre at y = 5.55 m)."""
    return Road(0.0, 0.0, 0.0, (Segment("straight", 1000.0),), lanes=2, lane_width_m=3.7)
