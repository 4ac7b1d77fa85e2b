"""``python -m sappc_controller``: the controller node (see :mod:`sappc_controller.node`)."""

import sys

from sappc_controller.node import main

sys.exit(main())
