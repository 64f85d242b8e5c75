"""ROS message types: rosbags typestores, field listings, and JSON renderings for the writers."""

from __future__ import annotations

import json
from dataclasses import fields as dataclass_fields
from dataclasses import is_dataclass
from functools import lru_cache
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.interfaces import Nodetype

from ..errors import LogReadError
from . import cdr
from .logtypes import TopicData

if TYPE_CHECKING:
    from rosbags.interfaces.typing import FieldDesc
    from rosbags.typesys.store import Typestore

#: a JSON Schema node
JsonSchema = dict[str, Any]

__all__ = ["typestore_for", "typestore_from_text", "check_type_graph", "numeric_leaves", "json_schema", "json_messages",
           "time_ordered"]

_INTS = {"int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "byte", "char"}


@lru_cache(maxsize=2)
def typestore_for(ros1: bool = False) -> Typestore:
    """The standard message definitions (ROS 1 Noetic or ROS 2 Humble). Shared: do not register into."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


def typestore_from_text(text: str, name: str, ros1: bool = False) -> Typestore:
    """A typestore holding the definitions a log carries (``.msg`` text with its dependencies).

    The log's own definition wins over the standard one, so older or custom message versions decode
    as recorded.

    Raises
    ------
    LogReadError
        The definitions name a type they do not define, or a type that contains itself
        (:func:`check_type_graph`); a hostile or careless schema must not reach the decoders, which
        recurse into nested types.
    """
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    types = get_types_from_msg(text, name)
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    try:
        store.register(types)
    except Exception:  # noqa: BLE001 - conflicts with a standard definition: start from builtins only
        base = store
        store = get_typestore(Stores.EMPTY)
        store.register({k: v for k, v in base.fielddefs.items() if k.startswith("builtin_interfaces/")})
        store.register(types)
    check_type_graph(store, name)
    return store


def check_type_graph(ts: Typestore, msgtype: str) -> None:
    """Check that every type ``msgtype`` nests is defined and none contains itself.

    Raises
    ------
    LogReadError
        Naming the undefined type, or the cycle (``A -> B -> A``).
    """
    done: set[str] = set()

    def visit(name: str, path: tuple[str, ...]) -> None:
        if name in path:
            cycle = " -> ".join(path[path.index(name):] + (name,))
            raise LogReadError(f"message type {msgtype} contains itself ({cycle}): not a finite message")
        if name in done:
            return
        if name not in ts.fielddefs:
            where = f" (in {path[-1]})" if path else ""
            raise LogReadError(f"message type {name} is not defined{where}")
        for _field, desc in ts.fielddefs[name][1]:
            inner = desc if desc[0] == Nodetype.NAME else (desc[1][0] if desc[0] != Nodetype.BASE else None)
            if inner is not None and inner[0] == Nodetype.NAME:
                visit(inner[1], path + (name,))
        done.add(name)

    visit(msgtype, ())


def numeric_leaves(ts: Typestore, msgtype: str, prefix: str = "") -> list[str]:
    """Dotted paths of the numeric fields of a type (arrays shown as ``name[N]``, sequences ``name[]``)."""
    out: list[str] = []
    for name, desc in ts.fielddefs[msgtype][1]:
        path = prefix + name
        if desc[0] == Nodetype.NAME:
            out.extend(numeric_leaves(ts, desc[1], path + "."))
        elif desc[0] == Nodetype.BASE:
            if desc[1][0] not in ("string", "wstring"):
                out.append(path)
        else:
            (elem, count) = desc[1]
            if elem[0] == Nodetype.BASE and elem[1][0] not in ("string", "wstring"):
                out.append(f"{path}[{count}]" if desc[0] == Nodetype.ARRAY else f"{path}[]")
    return out


def _schema_of(ts: Typestore, desc: FieldDesc) -> JsonSchema:
    if desc[0] == Nodetype.NAME:
        return {"type": "object",
                "properties": {n: _schema_of(ts, d) for n, d in ts.fielddefs[desc[1]][1]}}
    if desc[0] == Nodetype.BASE:
        typ = desc[1][0]
        if typ in ("string", "wstring"):
            return {"type": "string"}
        if typ == "bool":
            return {"type": "boolean"}
        return {"type": "integer" if typ in _INTS else "number"}
    return {"type": "array", "items": _schema_of(ts, desc[1][0])}


def json_schema(ts: Typestore, msgtype: str) -> JsonSchema:
    """A JSON Schema (draft 2020-12 subset) of a ROS message type, as MCAP ``jsonschema`` expects."""
    schema = _schema_of(ts, (Nodetype.NAME, msgtype))
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = msgtype
    return schema


def _to_plain(obj: object) -> Any:
    """A message (a rosbags dataclass) as nested JSON values."""
    if is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _to_plain(getattr(obj, f.name)) for f in dataclass_fields(obj) if f.name != "__msgtype__"}
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, list):
        return [_to_plain(v) for v in obj]
    return obj


def json_messages(ts: Typestore, msgtype: str, t: np.ndarray, fields: dict[str, np.ndarray],
                  frame_id: str = "map") -> list[bytes]:
    """JSON text of ``len(t)`` messages (all fields present; unspecified ones zero, quaternion w one).

    One message dict (the type's defaults) is filled in place with each message's numbers and dumped.
    """
    template = _to_plain(cdr.default_message(ts, msgtype, frame_id))
    columns: dict[str, list[Any]] = {k: np.asarray(v, dtype=np.float64).tolist() for k, v in fields.items()}
    if cdr.struct_fields(ts, msgtype, "header.stamp.sec") is not None:
        ns = np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)
        columns["header.stamp.sec"] = (ns // 1_000_000_000).tolist()
        columns["header.stamp.nanosec"] = (ns % 1_000_000_000).tolist()
    slots = []
    for path, column in columns.items():
        if cdr.leaf_paths(ts, msgtype, path) != [path]:
            raise ValueError(f"cannot write {path!r} of {msgtype}: not a numeric leaf")
        *parents, key = path.split(".")
        node = template
        for name in parents:
            node = node[name]
        slots.append((node, key, column))
    for path in fields:
        if not np.isfinite(np.asarray(fields[path], dtype=np.float64)).all():
            raise ValueError(f"{path}: JSON cannot hold NaN/inf")
    out = []
    for i in range(len(t)):
        for node, key, column in slots:
            node[key] = column[i]
        out.append(json.dumps(template, separators=(",", ":")).encode())
    return out


def time_ordered(topics: Sequence[TopicData], serialize: Callable[[TopicData], list[bytes]]
                 ) -> list[tuple[int, int, bytes]]:
    """Every message of ``topics`` as (topic index, time [ns], ``serialize(topic)``'s bytes), all serialised
    before the first is written, in time order (stable: ties keep topic order): what the log writers write."""
    stamps = [np.round(np.asarray(td.t, dtype=np.float64) * 1e9).astype(np.int64) for td in topics]
    datas = [serialize(td) for td in topics]
    which = np.concatenate([np.full(len(ns), k) for k, ns in enumerate(stamps)] or [np.zeros(0, int)])
    idx = np.concatenate([np.arange(len(ns)) for ns in stamps] or [np.zeros(0, int)])
    flat = np.concatenate(stamps or [np.zeros(0, np.int64)])
    order = np.lexsort((which, flat))
    return [(w, ns, datas[w][i]) for w, i, ns in zip(which[order].tolist(), idx[order].tolist(), flat[order].tolist())]
