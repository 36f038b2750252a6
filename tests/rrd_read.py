"""Reading .rrd files back in tests (rerun-sdk 0.41: rerun.chunk.RrdReader; see shared/notes/stack.md 3.4)."""

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from rerun.chunk import RrdReader


def read_column(path, entity, component, index="sample"):
    """(index values, cell values) of one component on one timeline, sorted by index; static rows skipped.

    A duration timeline (``t``) comes back in seconds."""
    idx, val = [], []
    for c in RrdReader(str(path)).stream().filter(content=entity, components=component).to_chunks():
        rb = c.to_record_batch()
        if index not in rb.schema.names:
            continue  # static chunk, or a chunk on another timeline
        column = rb.column(index)
        if pa.types.is_duration(column.type):
            column = pc.divide(column.cast(pa.int64()).cast(pa.float64()), 1e9)
        idx += column.to_pylist()
        val += rb.column(component).to_pylist()
    order = np.argsort(idx, kind="stable")
    return np.asarray(idx)[order], [val[i] for i in order]


def read_static(path, entity, component):
    """The cells of a static component."""
    out = []
    for c in RrdReader(str(path)).stream().filter(content=entity, components=component).to_chunks():
        rb = c.to_record_batch()
        if component in rb.schema.names:
            out += rb.column(component).to_pylist()
    return out


def scalars(path, entity, index="sample"):
    """(index, values (n, k)) of a Scalars entity."""
    idx, cells = read_column(path, entity, "Scalars:scalars", index)
    return idx, np.array([c if c is not None else [np.nan] for c in cells], dtype=float)


def entity_paths(path):
    return {c.entity_path for c in RrdReader(str(path)).stream().to_chunks()}


def timelines(path, entity):
    """Names of the index columns an entity's chunks carry (besides the row id)."""
    names = set()
    for c in RrdReader(str(path)).stream().filter(content=entity).to_chunks():
        names |= {n for n in c.to_record_batch().schema.names if ":" not in n and n != "rerun.controls.RowId"}
    return names


def blueprint_views(path):
    """The views of the file's blueprint: list of dicts with class, name, origin, contents."""
    reader = RrdReader(str(path))
    (store,) = reader.blueprints()
    views = {}
    for c in reader.stream(store=store).to_chunks():
        path_ = c.entity_path
        if not path_.startswith("/view/"):
            continue
        key = path_.split("/")[2]
        rb = c.to_record_batch()
        view = views.setdefault(key, {})
        for column, name in (("ViewBlueprint:class_identifier", "class"), ("ViewBlueprint:display_name", "name"),
                             ("ViewBlueprint:space_origin", "origin"), ("ViewContents:query", "contents")):
            if column in rb.schema.names:
                value = rb.column(column).to_pylist()[-1]
                view[name] = value if column == "ViewContents:query" else value[0]
    return list(views.values())


def blueprint_timeline(path):
    """The timeline the blueprint's time panel shows, or None."""
    reader = RrdReader(str(path))
    (store,) = reader.blueprints()
    for c in reader.stream(store=store).to_chunks():
        rb = c.to_record_batch()
        if "TimePanelBlueprint:timeline" in rb.schema.names:
            return rb.column("TimePanelBlueprint:timeline").to_pylist()[-1][0]
    return None
