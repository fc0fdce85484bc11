"""``import vdc.catalog``: many recordings as one dataset, from Python (the facade over
``analysis.catalog``; the command line is ``vdc-analyse catalog``).

* ``vdc.catalog.query(folders_or_url, where=...)``: the frames of the matching segments, one table;
* ``vdc.catalog.open_catalog(folders)``: a context manager with the running dataset;
* ``vdc.catalog.serve(...)``, ``scan(...)``, ``segment_table(...)``: the pieces the command uses.

The names are ``analysis.catalog``'s public face, listed there once; each loads on first use
(Rerun and polars with it), so ``import vdc.catalog`` alone stays light.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from analysis.catalog import _FACE  # the face's own table: the names are listed once
from vdc.lazy import lazy_face

if TYPE_CHECKING:  # the real types for IDEs and type checkers, as the face declares them
    from analysis.catalog import *  # noqa: F403

__all__ = sorted(_FACE)
__getattr__, __dir__ = lazy_face(__name__, _FACE)
