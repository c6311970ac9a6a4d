"""Pipelines: what torchik does with the method and the data, as plain functions and dataclasses
that return results and never parse arguments or print.

track (a recording tracked and reported), evaluation (link motion, errors, statistics),
retarget (a human recording to iCub), experiment (the paper's comparison), bench (throughput),
rrd (rerun recordings), diagnosis (the closed loop on measured data), cohort (a study on Dask),
memory (keep freed memory for large batches).
"""
