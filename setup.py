"""tipbot: LEGO EV3 three-link balancing robot.

Two packages in one source tree:
  - tipbot_fw: the firmware that runs on the brick (ev3dev-stretch: Python 3.5.3, numpy 1.12,
    python-ev3dev2 2.1.0). Its only third-party requirement is numpy; python-ev3dev2 is imported
    for device discovery on the brick only.
  - hostsim: host-only tools (model, gains design, simulator, replay; Python 3.11+), installed
    with the `host` extra. Day-to-day, `make venv` installs the exact host pins of
    requirements-host.txt instead, and the packages are used from the source tree.
"""
import os
import re

from setuptools import setup

HERE = os.path.dirname(os.path.abspath(__file__))


def version():
    with open(os.path.join(HERE, "tipbot_fw", "__init__.py")) as f:
        return re.search(r"^__version__ = ['\"]([^'\"]+)['\"]", f.read(), re.M).group(1)


setup(
    name="tipbot",
    version=version(),
    description="Firmware and host tools for a LEGO EV3 three-link balancing robot",
    packages=["tipbot_fw", "tipbot_fw.cores", "tipbot_fw.io", "tipbot_fw.guard", "tipbot_fw.record",
              "tipbot_fw.drive", "hostsim", "hostsim.model", "hostsim.world", "hostsim.sim",
              "hostsim.studies", "hostsim.logs"],
    package_data={"tipbot_fw": ["*.json"], "hostsim.model": ["data/*.json"]},
    python_requires=">=3.5",
    install_requires=["numpy>=1.12"],
    # The host tools on PATH (pip install -e .): tipbot-host VERB is python -m hostsim VERB.
    entry_points={"console_scripts": ["tipbot-host = hostsim.__main__:main"]},
    extras_require={
        "robot": ["python-ev3dev2==2.1.0"],
        "host": ["numpy", "scipy", "sympy", "control", "matplotlib", "tqdm"],
        "test": ["pytest", "vermin", "python-ev3dev2==2.1.0"],
    },
)
