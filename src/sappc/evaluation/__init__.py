"""What a run is and how it is scored, shared by offline runs, campaigns and bags: the time
histories (``history``) and the metrics (``metrics``)."""
