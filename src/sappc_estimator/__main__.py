"""``python -m sappc_estimator``: the estimator node (see :mod:`sappc_estimator.node`)."""

import sys

from sappc_estimator.node import main

sys.exit(main())
