"""Reading recorded bags without ROS: the MCAP scanner (``mcap_scan``), the CDR decoders of the
contract's types (``cdr``), and bags as arrays, runs and metrics (``read``).  Errors:
:class:`~sappc.bag.read.BagError`."""
