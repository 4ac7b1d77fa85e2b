"""``python -m sappc_modes``: the mode node (see :mod:`sappc_modes.node`)."""

import sys

from sappc_modes.node import main

sys.exit(main())
