"""``python -m sappc_momentum``: the momentum-management node (see :mod:`sappc_momentum.node`)."""

import sys

from sappc_momentum.node import main

sys.exit(main())
