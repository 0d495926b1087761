"""What runs on the brick, for the tests that check it statically (Python 3.5, numpy 1.12)."""
import os
from conftest import REPO

ROBOT_DIRS = ("tipbot_fw", "ev3")


def robot_python_files():
    """The .py files, and extension-less files with a python shebang (ev3/tipbot), under ROBOT_DIRS."""
    out = []
    for top in ROBOT_DIRS:
        for dirpath, dirnames, filenames in os.walk(os.path.join(REPO, top)):
            dirnames[:] = [d for d in dirnames if d != "__pycache__"]
            for name in filenames:
                path = os.path.join(dirpath, name)
                if name.endswith(".py"):
                    out.append(path)
                elif "." not in name:
                    with open(path, "rb") as f:
                        first = f.readline()
                    if first.startswith(b"#!") and b"python" in first:
                        out.append(path)
    return sorted(out)
