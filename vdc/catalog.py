"""``import vdc.catalog``: many recordings as one dataset, from Python (the facade over
``analysis.catalog.build``; the command line is ``vdc-analyse catalog``).

* ``vdc.catalog.query(folders_or_url, where=...)``: the frames of the matching segments, one table;
* ``vdc.catalog.open_catalog(folders)``: a context manager with the running dataset;
* ``vdc.catalog.serve(...)``, ``scan(...)``, ``segment_table(...)``: the pieces the command uses.

Importing it loads Rerun and polars: ``import vdc`` alone stays light.
"""

from analysis.catalog.build import CatalogSettings, scan
from analysis.catalog.query import query, query_to, segment_table, select_segments
from analysis.catalog.server import Catalog, dataset_url, open_catalog, serve

__all__ = [
    "Catalog",
    "CatalogSettings",
    "dataset_url",
    "open_catalog",
    "query",
    "query_to",
    "scan",
    "segment_table",
    "select_segments",
    "serve",
]
