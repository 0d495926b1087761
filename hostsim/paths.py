"""Where the host tools find the repository's files: they run from the source tree."""
import os

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GAINS_DIR = os.path.join(REPO_ROOT, "gains")
CACHE_DIR = os.path.join(REPO_ROOT, ".cache")


def out_dir(*parts):
    """A directory under out/, where the host tools write their results by default."""
    return os.path.join(REPO_ROOT, "out", *parts)
