"""Fixtures shared by several test modules."""
import pytest

from hostsim.world.fake_ev3 import FakeEV3


@pytest.fixture
def fake():
    """A fresh fake EV3 sysfs tree (default devices), removed after the test."""
    f = FakeEV3()
    yield f
    f.close()
