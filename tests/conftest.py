"""Fixtures and paths shared by the test modules."""
import os

import pytest

from hostsim.world.fake_ev3 import FakeEV3

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GAINS_DIR = os.path.join(REPO, "gains")
PHYSICAL_GAINS = os.path.join(GAINS_DIR, "physical.json")
PAPER_GAINS = os.path.join(GAINS_DIR, "paper.json")
PARAMS_FILE = os.path.join(REPO, "params", "robot.json")


def gains_path(variant):
    """The committed gains file of a model variant."""
    return os.path.join(GAINS_DIR, variant + ".json")


@pytest.fixture
def fake():
    """A fresh fake EV3 sysfs tree (default devices), removed after the test."""
    f = FakeEV3()
    yield f
    f.close()


@pytest.fixture(scope="module")
def params():
    """The robot's parameters (params/robot.json), validated."""
    from hostsim.model.params import load_params
    return load_params()


@pytest.fixture(autouse=True)
def _not_over_ssh(monkeypatch):
    """The firmware's words go to stderr only when started over ssh (SSH_CONNECTION): tests
    that read the brick's screen (stdout) must not depend on how the suite itself was started."""
    monkeypatch.delenv("SSH_CONNECTION", raising=False)
