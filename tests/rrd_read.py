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


def _last(rb, column):
    return rb.column(column).to_pylist()[-1] if column in rb.schema.names else None


def blueprint_details(path):
    """Each view of the blueprint with what makes it read right: dicts with ``class``, ``name``,
    ``origin``, ``contents``, ``range_kinds`` (the time axis's start and end boundary kinds: 1
    cursor-relative, 2 absolute, 3 infinite), ``text_columns`` ([(kind, visible)]: 1 entity path, 2
    level, 3 body), ``timeline_columns`` and ``eye`` (the 3-D camera's position), None when unset."""
    reader = RrdReader(str(path))
    (store,) = reader.blueprints()
    views = {}
    for c in reader.stream(store=store).to_chunks():
        parts = c.entity_path.split("/")
        if len(parts) < 3 or parts[1] != "view":
            continue
        view = views.setdefault(parts[2], {"range_kinds": None, "text_columns": None, "timeline_columns": None,
                                           "eye": None})
        rb = c.to_record_batch()
        for column, name in (("ViewBlueprint:class_identifier", "class"), ("ViewBlueprint:display_name", "name"),
                             ("ViewBlueprint:space_origin", "origin")):
            if column in rb.schema.names:
                view[name] = _last(rb, column)[0]
        if "ViewContents:query" in rb.schema.names:
            view["contents"] = _last(rb, "ViewContents:query")
        if "TimeAxis:view_range" in rb.schema.names:
            cell = rb.column("TimeAxis:view_range")[-1].values
            view["range_kinds"] = (cell.field("start").type_codes[0].as_py(), cell.field("end").type_codes[0].as_py())
        if "TextLogColumns:text_log_columns" in rb.schema.names:
            view["text_columns"] = [(d["kind"], d["visible"]) for d in _last(rb, "TextLogColumns:text_log_columns")]
            view["timeline_columns"] = _last(rb, "TextLogColumns:timeline_columns")
        if "EyeControls3D:position" in rb.schema.names:
            view["eye"] = _last(rb, "EyeControls3D:position")[0]
    return list(views.values())


def panel_states(path):
    """{panel entity: state} of the blueprint's side panels (1 hidden, 2 collapsed, 3 expanded)."""
    reader = RrdReader(str(path))
    (store,) = reader.blueprints()
    states = {}
    for c in reader.stream(store=store).to_chunks():
        rb = c.to_record_batch()
        for column in ("PanelBlueprint:state", "TimePanelBlueprint:state"):
            if column in rb.schema.names:
                states[c.entity_path] = _last(rb, column)[0]
    return states


def application_ids(path):
    """The application ids of the file's recording and blueprint."""
    reader = RrdReader(str(path))
    return {entry.application_id for entry in reader.recordings() + reader.blueprints()}


def static_labels(path):
    """Every label a 3-D view shows at rest, as (entity, text, position in the file's root frame).

    Positions as Rerun places them: an arrow's at 45 % of its length from its origin, a point's at
    the point; static translations of the parents applied, moving ones (rotations over time) taken
    at identity. Batches with ``show_labels`` false are left out.
    """
    translation, found = {}, []
    for c in RrdReader(str(path)).stream().to_chunks():
        rb = c.to_record_batch()
        if "Transform3D:translation" in rb.schema.names:
            value = _last(rb, "Transform3D:translation")
            if value is not None:
                translation[c.entity_path] = np.asarray(value[0] if np.ndim(value) > 1 else value, dtype=float)
        show = _last(rb, next((n for n in rb.schema.names if n.endswith(":show_labels")), "none"))
        for archetype, position in (("Arrows3D", None), ("Points3D", "Points3D:positions")):
            labels = _last(rb, f"{archetype}:labels")
            if not labels or (show is not None and not show[0]):
                continue
            if archetype == "Arrows3D":
                vectors = np.asarray(_last(rb, "Arrows3D:vectors"), dtype=float)
                origins = _last(rb, "Arrows3D:origins")
                origins = np.zeros_like(vectors) if origins is None else np.asarray(origins, dtype=float)
                points = origins + 0.45 * vectors
            else:
                points = np.asarray(_last(rb, position), dtype=float)
            found += [(c.entity_path, text, points[min(k, len(points) - 1)]) for k, text in enumerate(labels)]
    out = []
    for entity, text, point in found:
        parts = entity.split("/")
        offset = sum((translation.get("/".join(parts[:k]), np.zeros(3)) for k in range(2, len(parts) + 1)),
                     np.zeros(3))
        out.append((entity, text, point + offset))
    return out
