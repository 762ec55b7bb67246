"""python -m atacama_sim generate ..."""

import sys

from atacama_sim.cli import main

sys.exit(main())
