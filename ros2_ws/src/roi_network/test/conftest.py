import sys
from pathlib import Path

# pytest runs with --import-mode=importlib (test files of different packages share
# names), so a helper module beside the tests must be put on the path explicitly.
sys.path.insert(0, str(Path(__file__).parent))
