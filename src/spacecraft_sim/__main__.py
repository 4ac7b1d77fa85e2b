"""``python -m spacecraft_sim``: the plant node (see :mod:`spacecraft_sim.plant_node`)."""

import sys

from spacecraft_sim.plant_node import main

sys.exit(main())
