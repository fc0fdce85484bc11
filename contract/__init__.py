"""What capture and analysis agree on, imported by both (neither imports the other for it):

* ``contract.recording``: the recording contract: application id, timelines, entity paths,
  property sections (DESIGN.md);
* ``contract.provenance``: the package versions and the machine every recording and table
  carries, so results from two machines can be compared;
* ``contract.parquet_io``: the table contract: atomic Parquet files with that provenance in
  their key-value metadata (analysis tables, the runs table of ``vdc-capture sweep``);
* ``contract.executors``: where independent tasks run (a local process pool, a Dask cluster),
  for batch analysis and for capture campaigns alike.
"""
