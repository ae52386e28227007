"""`sofia atlas`: which campaign sees which effect at what size, from many simulated campaigns on Dask.

grid (the cells), task (one campaign plus compare, one row), store (the Parquet table, resumable),
engine (serial loop, LocalCluster or a scheduler), stats (detection, sizes, sigmas, confusions,
Table 6.5), report (text table, HTML with PNGs), cli (the command). docs/atlas.md is the contract.
The modules are imported one by one (``sofia_ros.atlas.grid`` ...): building the `sofia` parser
must not load Dask, pyarrow or matplotlib.
"""

__all__: list[str] = []
