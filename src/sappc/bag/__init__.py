"""Reading recorded bags without ROS: the MCAP scanner (``mcap_scan``), the CDR decoders of the
contract's types (``cdr``), and bags as arrays, runs and metrics (``read``); and an offline run's
record written as a bag (``write_offline``).  Errors: :class:`~sappc.bag.read.BagError`."""
