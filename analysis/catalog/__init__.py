"""``vdc-analyse catalog``: every recording in some folders as one Rerun dataset.

Modules: ``build`` (what is registered: settings, the folder scan, repairs) → ``server`` (the
catalog server and web viewer on 127.0.0.1) → ``query`` (queries by folder or URL). These are
the only modules that know Rerun's catalog API; ``import vdc.catalog`` is the same from Python.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from vdc.lazy import lazy_face

if TYPE_CHECKING:
    from analysis.catalog.build import CatalogSettings, scan
    from analysis.catalog.query import query, query_to, segment_table, select_segments
    from analysis.catalog.server import Catalog, dataset_url, open_catalog, serve

# the public face: name -> the module that defines it (loaded on first use)
_FACE = {
    "CatalogSettings": "analysis.catalog.build",
    "scan": "analysis.catalog.build",
    "open_catalog": "analysis.catalog.server",
    "serve": "analysis.catalog.server",
    "dataset_url": "analysis.catalog.server",
    "Catalog": "analysis.catalog.server",
    "query": "analysis.catalog.query",
    "query_to": "analysis.catalog.query",
    "segment_table": "analysis.catalog.query",
    "select_segments": "analysis.catalog.query",
}
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
__getattr__, __dir__ = lazy_face(__name__, _FACE)
