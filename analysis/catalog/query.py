"""Queries over a catalog (``vdc-analyse catalog query``, ``vdc.catalog.query``): the frames
and model outputs of the segments that match, read in one ``reader()`` call, from folders (a
server started for the query) or from a catalog already serving at a URL."""

from __future__ import annotations

import contextlib
import dataclasses
import re
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from analysis.catalog.build import BASE, SUMMARY, CatalogSettings, is_catalog_url
from analysis.catalog.server import Catalog, _require_catalog, open_catalog
from analysis.recordings.loading import FRAMES_COLUMNS, from_signals, signals_table
from analysis.recordings.reader import Recording
from vdc.errors import UserError
from vdc.parquet_io import table_set, write_parquet
from vdc.recording import (
    DATASET_ROOT,
    FRAME_TIMELINE,
    MODEL_VARIANTS_ROOT,
)


def segment_table(cat: Catalog) -> pl.DataFrame:
    """One row per segment: its id, layers, and the summary properties as plain columns
    (``source``, ``scene``, ``seed``, ``mean_omega_dps``, ...)."""
    return _summary_columns(pl.from_arrow(cat.dataset.segment_table().to_arrow_table()))


def _summary_columns(seg: pl.DataFrame) -> pl.DataFrame:
    """A dataset's segment table reduced to the id, the layers and the summary properties."""
    prefix = f"property:{SUMMARY}:"
    cols = [c for c in seg.columns if c.startswith(prefix)]
    return seg.select(
        pl.col("rerun_segment_id").alias("recording_id"),
        pl.col("rerun_layer_names").alias("layers"),
        *[pl.col(c).list.first().alias(c[len(prefix) :]) for c in cols],
    ).sort("recording_id")


def select_segments(table: pl.DataFrame, where: dict[str, Any] | None) -> list[str]:
    """The segment ids whose summary properties equal every ``where`` value (compared as
    text, so ``seed=1`` matches 1)."""
    rows = table
    for key, value in (where or {}).items():
        if key not in rows.columns:
            raise UserError(
                f"--where {key}: no such property (known: {', '.join(sorted(table.columns[2:]))})."
            )
        rows = rows.filter(pl.col(key).cast(pl.String) == str(value))
    return rows["recording_id"].to_list()


def _signals_of(table: pl.DataFrame) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """One segment's rows of a reader table as ``Recording.signals()`` gives them: per scalar
    entity, (frame, t_s, values (N, K)) over the frames where it was logged."""
    out = {}
    frame = table["frame"].to_numpy()
    t = (
        (table["time"].cast(pl.Int64).to_numpy() / 1e9)
        if "time" in table.columns
        else frame * np.nan
    )
    for col in table.columns:
        if not col.endswith(":Scalars:scalars"):
            continue
        entity = col.split(":")[0]
        values = table[col]
        keep = values.is_not_null().to_numpy()
        if not keep.any():
            continue
        arr = np.asarray(values.filter(pl.Series(keep)).to_list(), dtype=np.float64)
        out[entity] = (frame[keep], t[keep], arr.reshape(len(arr), -1))
    return out


@dataclasses.dataclass
class _Selection:
    """What one query reads: the dataset view, each segment's properties and its variants'
    model names ``{segment: {entity part: model name}}``."""

    view: Any
    props: dict[str, dict[str, dict[str, Any]]]
    variant_names: dict[str, dict[str, str]]
    url: str  # the server read from
    # the files found but not served, with the reason: [(file, one-line reason)]; none known
    # for a catalog read by its URL (its server chose what it serves)
    left_out: list[tuple[str, str]] = dataclasses.field(default_factory=list)


def _property_key(entity: str) -> str:
    """A variant's entity part as a property field's name reads in a segment table (the
    server spells ``avdm_beta_0.5`` as ``avdm_beta_0_5``): one key for both readings."""
    return re.sub(r"[^A-Za-z0-9_]", "_", entity)


def _properties_from_segment_table(seg: pl.DataFrame) -> dict[str, dict[str, dict[str, Any]]]:
    """``{segment: {section: {field: value}}}`` from a segment table's ``property:S:F``
    columns, decoded as ``Recording.properties()`` decodes a file's."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    cols = [c for c in seg.columns if c.startswith("property:") and c.count(":") >= 2]
    for row in seg.select("rerun_segment_id", *cols).iter_rows(named=True):
        props: dict[str, dict[str, Any]] = {}
        for c in cols:
            v = row[c]
            if v is None:
                continue
            _, section, field = c.split(":", 2)
            props.setdefault(section, {})[field] = (
                v[0] if isinstance(v, list) and len(v) == 1 else v
            )
        out[row["rerun_segment_id"]] = props
    return out


@contextlib.contextmanager
def _remote_dataset(url: str, settings: CatalogSettings) -> Iterator[tuple[Any, str]]:
    """The dataset of a catalog already serving at ``url`` (``settings.dataset``, or its only
    one); nothing is started or registered."""
    rr = _require_catalog()
    try:
        client = rr.catalog.CatalogClient(url)
        names = list(client.dataset_names())
    except Exception as exc:  # connection refused, a wrong scheme, a server of another kind
        raise UserError(f"no catalog answers at {url}: {str(exc).splitlines()[0][:200]}") from None
    name = settings.dataset or (names[0] if len(names) == 1 else None)
    if name is None or name not in names:
        raise UserError(
            f"the catalog at {url} serves {', '.join(names) or 'no dataset'}: "
            + ("name one with --dataset" if name is None else f"no dataset {name!r}")
        )
    with _server_answers(url):
        ds = client.get_dataset(name)
    yield ds, name


# the wrappers the server's client puts before its reason (DataFusion over an FFI boundary)
_WRAPPERS = re.compile(r"^((DataFusion|FFI|External) error: )+")


@contextlib.contextmanager
def _server_answers(where: str) -> Iterator[None]:
    """A catalog server's failure while it answers (killed mid-query; a recording it serves
    cut, truncated or gone) as one line naming ``where`` and the server's own reason: a
    :class:`UserError` (exit status 2), never the client's traceback. Ours pass as they are."""
    try:
        yield
    except UserError:
        raise
    except Exception as exc:  # the client's errors (RuntimeError, DataFusion's Exception)
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        reason = _WRAPPERS.sub("", first)[:300]
        raise UserError(
            f"the catalog at {where} failed mid-query (its server stopped or could not read a "
            f"recording): {reason}"
        ) from None


@contextlib.contextmanager
def _select(
    sources: Sequence[str | Path],
    where: dict[str, Any] | None,
    layers: Sequence[str] | None,
    settings: CatalogSettings,
    notice: Callable[[str], None] | None,
) -> Iterator[_Selection]:
    """The segments matching ``where`` with the chosen layers, from folders (a catalog started
    for the query) or from one catalog URL (a running server, as a lab's shared one)."""

    urls = [s for s in sources if is_catalog_url(s)]
    if urls:
        if len(sources) != 1:
            raise UserError("give either folders or one catalog URL (rerun+http://HOST:PORT).")
        if layers:
            raise UserError(
                "from a catalog URL every layer's variants are read: leave out --layer."
            )
        with _remote_dataset(str(urls[0]), settings) as (ds, _name):
            with _server_answers(str(urls[0])):
                seg = pl.from_arrow(ds.segment_table().to_arrow_table())
            ids = select_segments(_summary_columns(seg), where)
            if not ids:
                raise UserError(f"no segment matches {where}.")
            props = _properties_from_segment_table(seg)
            names = {
                rid: {_property_key(k): v for k, v in p.get("model_variants", {}).items()}
                for rid, p in props.items()
            }
            yield _Selection(ds.filter_segments(ids), props, names, str(urls[0]))
        return
    with open_catalog(sources, settings, notice) as cat:
        ids = select_segments(segment_table(cat), where)
        if not ids:
            raise UserError(f"no segment matches {where}.")
        chosen = [BASE, *(layers if layers is not None else [n for n in cat.found.layers])]
        unknown = [n for n in chosen if n != BASE and n not in cat.found.layers]
        if unknown:
            raise UserError(f"no layer {unknown[0]!r} (layers: {', '.join(cat.found.layers)}).")
        names: dict[str, dict[str, str]] = {}
        for layer in chosen[1:]:
            for rid, path in cat.found.layers.get(layer, []):
                recorded = Recording(path).properties().get("model_variants", {})
                names.setdefault(rid, {}).update({_property_key(k): v for k, v in recorded.items()})
        # a layer left out: its entity paths are left out of the one read
        hidden = sorted(
            {e for n, ents in cat.found.entities.items() if n not in chosen for e in ents}
        )
        view = cat.dataset.filter_segments(ids).filter_contents(
            ["+ /**", *[f"- {e}" for e in hidden]]
        )
        props = {s.recording_id: Recording(s.path).properties() for s in cat.found.segments}
        yield _Selection(view, props, names, cat.url, list(cat.found.unregistered))


def query(
    folders: Sequence[str | Path] | str,
    where: dict[str, Any] | None = None,
    layers: Sequence[str] | None = None,
    settings: CatalogSettings = CatalogSettings(),
    notice: Callable[[str], None] | None = None,
) -> dict[str, pl.DataFrame]:
    """The ``frames`` and ``model_outputs`` tables (and, over dataset episodes, ``measures``:
    one row per camera and frame, a column per measure) of the segments whose summary
    properties match ``where``, read in one ``reader()`` call over the catalog, with the
    variants of the given ``layers`` (default: all) as models of their own: the tables
    ``tables`` writes for the same recordings (and ``batch`` for the variants); and
    ``left_out``: each file found in the folders but not served (``source``, ``reason``: a
    recording cut short, another application's, the same recording twice, ...), also said
    through ``notice``.

    ``folders`` are folders of recordings (a catalog is started for the query and stopped
    after it), or one catalog URL, ``"rerun+http://HOST:PORT"``: a catalog already serving
    (``vdc-analyse catalog serve``, a lab's shared server), read as it is."""

    sources = [folders] if isinstance(folders, (str, Path)) else list(folders)
    with _select(sources, where, layers, settings, notice) as sel:
        with _server_answers(sel.url):
            raw = pl.from_arrow(sel.view.reader(index=FRAME_TIMELINE).to_arrow_table())
    frames, outputs, measures = [], [], []
    scalar = [c for c in raw.columns if c.endswith(":Scalars:scalars")]
    raw = raw.select(
        "rerun_segment_id", FRAME_TIMELINE, *(["time"] if "time" in raw.columns else []), *scalar
    )
    for (rid,), part in raw.sort("rerun_segment_id", FRAME_TIMELINE).group_by(
        "rerun_segment_id", maintain_order=True
    ):
        sig = _signals_of(part)
        f, logged, _ = from_signals(sig, sel.props[rid], rid)
        frames.append(f)
        models = dict(logged)
        for entity in {e.split("/")[2] for e in sig if e.startswith(MODEL_VARIANTS_ROOT + "/")}:
            df = signals_table(sig, f"{MODEL_VARIANTS_ROOT}/{entity}/")
            name = sel.variant_names.get(rid, {}).get(_property_key(entity), entity)
            # a variant named like the online model recomputes its logged outputs (bit for
            # bit): the logged ones stay
            if df is not None and name not in models:
                models[name] = df
        measures += _measures_of(sig, rid)
        for name, df in models.items():
            outputs.append(
                df.with_columns(
                    pl.lit(rid).alias("recording_id"), pl.lit(name).alias("model")
                ).select("recording_id", "model", pl.all().exclude("recording_id", "model"))
            )
    # a dataset episode has no model of its own (its measures are a table of their own)
    no_outputs = {"recording_id": pl.String, "model": pl.String, "frame": pl.Int64}
    tables = {
        "frames": pl.concat(frames).select(FRAMES_COLUMNS).sort("recording_id", "frame"),
        "model_outputs": pl.concat(outputs, how="diagonal_relaxed").sort(
            "recording_id", "model", "frame"
        )
        if outputs
        else pl.DataFrame(schema=no_outputs | {"t_s": pl.Float64}),
    }
    if measures:
        tables["measures"] = pl.concat(measures, how="diagonal_relaxed").sort(
            "recording_id", "camera", "frame"
        )
    tables["left_out"] = pl.DataFrame(
        sel.left_out, schema={"source": pl.String, "reason": pl.String}, orient="row"
    )
    return tables


def _measures_of(
    sig: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], rid: str
) -> list[pl.DataFrame]:
    """A dataset episode's measures (``vdc-analyse dataset``: ``/dataset/<camera>/measures/*``),
    one table per camera: recording_id, camera, frame, t_s, a column per measure."""
    out = []
    cams = {e.split("/")[2] for e in sig if e.startswith(DATASET_ROOT + "/") and "/measures/" in e}
    for cam in sorted(cams):
        df = signals_table(sig, f"{DATASET_ROOT}/{cam}/measures/")
        if df is not None:
            out.append(
                df.select(pl.lit(rid).alias("recording_id"), pl.lit(cam).alias("camera"), pl.all())
            )
    return out


def query_to(
    folders: Sequence[str | Path],
    settings: CatalogSettings,
    out: str | Path,
    notice: Callable[[str], None] | None = None,
) -> list[tuple[Path, pl.DataFrame]]:
    """``vdc-analyse catalog query``: :func:`query` written to ``out`` as ``frames.parquet``,
    ``model_outputs.parquet`` (and ``measures.parquet`` over dataset episodes; published
    whole), with the selection in their metadata."""

    res = query(folders, settings.where_dict(), settings.layers or None, settings, notice)
    meta = {"folders": [str(f) for f in folders], "where": settings.where_dict()}
    with table_set(Path(out)) as stage:
        for name, df in res.items():
            write_parquet(df, stage / f"{name}.parquet", meta)
    return [(Path(out) / f"{name}.parquet", df) for name, df in res.items()]
