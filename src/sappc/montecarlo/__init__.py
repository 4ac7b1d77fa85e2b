"""Monte Carlo campaigns (``sappc montecarlo``): the scenario's ``montecarlo`` section, per-run
random inputs, chunked runs on local workers or a Dask cluster, the table, summary and figures."""
