import sys
from pathlib import Path

# pytest runs with --import-mode=importlib: put the helper module beside the tests on the path.
sys.path.insert(0, str(Path(__file__).parent))
