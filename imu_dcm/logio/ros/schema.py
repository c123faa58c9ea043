"""Message definitions as field lists, from ros2msg, ros1msg or ros2idl schemas.

A plain ``.msg`` text (``ros2msg`` / ``ros1msg`` with its ``MSG:`` dependencies, what ROS
recorders store) is read here, field by field, exactly as :mod:`rosbags.typesys` reads it
(tested against it); anything else in one (quotes, annotations, a line this reader does not
know) and every ``ros2idl`` schema go to rosbags' parser, whose import costs more than reading
a log's schemas. A channel without a schema (sqlite3 bags of Humble and older) takes its
definition from rosbags' built-in type store. The result is a plain map
``type name -> [Field]`` that :mod:`imu_dcm.logio.ros.cdr` walks. A corrupt schema, one that is too
large, or one whose types nest deeper than :data:`MAX_DEPTH` (or contain themselves) raises
:class:`~imu_dcm.errors.LogError`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache

from imu_dcm.errors import LogError
from imu_dcm.logio.ros.collect import Conn

__all__ = [
    "MAX_DEPTH",
    "MAX_SCHEMA_BYTES",
    "PRIM",
    "Defs",
    "Field",
    "definitions",
    "norm_type",
    "typestore_for",
]


#: Primitive ROS types and their little-endian numpy dtypes.
PRIM = {
    "bool": "u1",
    "byte": "u1",
    "char": "u1",
    "octet": "u1",
    "int8": "i1",
    "uint8": "u1",
    "int16": "i2",
    "uint16": "u2",
    "int32": "i4",
    "uint32": "u4",
    "int64": "i8",
    "uint64": "u8",
    "float32": "f4",
    "float64": "f8",
}
#: Deepest type nesting followed (real messages nest < 10 levels).
MAX_DEPTH = 64
#: Largest schema text parsed (bytes).
MAX_SCHEMA_BYTES = 1 << 20
_TIME = [("sec", "int32"), ("nanosec", "uint32")]


@dataclass(frozen=True)
class Field:
    """One field: ``base`` is a primitive name, "string" or a full type "pkg/msg/Name";
    ``array`` is None, "fixed" (``count`` elements) or "seq" (length-prefixed)."""

    name: str
    base: str
    array: str | None
    count: int


Defs = dict[str, list[Field]]


def norm_type(name: str) -> str:
    """``pkg/Name`` or ``pkg/msg/Name`` -> ``pkg/msg/Name``."""
    parts = name.strip().split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name.strip()


def _base_name(desc) -> str:
    kind, arg = desc
    if int(kind) == 1:  # Nodetype.BASE: (name, string bound)
        name = arg[0]
        return "string" if name in ("string", "wstring") else name
    return str(arg)  # Nodetype.NAME: full type name


def _convert(typesdict) -> Defs:
    defs: Defs = {}
    for tname, (_consts, fields) in typesdict.items():
        out = []
        for fname, desc in fields:
            if fname == "structure_needs_at_least_one_member":
                continue
            kind = int(desc[0])
            if kind in (1, 2):
                out.append(Field(fname, _base_name(desc), None, 0))
            else:  # 3 ARRAY ((sub), count) / 4 SEQUENCE ((sub), bound)
                sub, num = desc[1]
                out.append(
                    Field(
                        fname,
                        _base_name(sub),
                        "fixed" if kind == 3 else "seq",
                        int(num) if kind == 3 else 0,
                    )
                )
        defs[tname] = out
    return _with_time(defs)


def _with_time(defs: Defs) -> Defs:
    """``defs`` with the builtin Time and Duration where the schema leaves them out."""
    for builtin in ("builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration"):
        defs.setdefault(builtin, [Field(n, t, None, 0) for n, t in _TIME])
    return defs


def _check_depth(defs: Defs, root: str) -> None:
    """Refuse self-containing types and nesting deeper than MAX_DEPTH (iteratively)."""
    depth: dict[str, int] = {}
    stack: list[tuple[str, int, frozenset]] = [(root, 0, frozenset())]
    while stack:
        name, d, seen = stack.pop()
        if d > MAX_DEPTH:
            raise LogError(
                f"Expected message types nested at most {MAX_DEPTH} deep, got deeper in {root}"
            )
        if depth.get(name, -1) >= d:
            continue
        depth[name] = d
        for f in defs.get(name, []):
            if f.base in defs:
                if f.base in seen or f.base == name:
                    if f.array is None:
                        raise LogError(
                            f"Expected a message type that does not contain itself, "
                            f"got {f.base} inside {name}"
                        )
                    continue
                stack.append((f.base, d + 1, seen | {name}))


def _idl_types(text: str) -> dict:
    """Types of an IDL schema, possibly several IDL files separated by ``=== / IDL: name``."""
    from rosbags.typesys import get_types_from_idl  # lazy: heavy, see _definitions

    types: dict = {}
    for piece in re.split(r"^=+[ \t]*$", text, flags=re.MULTILINE):
        body = re.sub(r"\A\s*IDL:[^\n]*\n", "", piece)
        if body.strip():
            types.update(get_types_from_idl(body))
    return types


# The ``.msg`` grammar as rosbags reads it, for the fast path. Names are matched as plain
# tokens and checked in code (no nested quantifiers: a long odd line cannot make a regex
# backtrack for ever).
_BASE = re.compile(r"(bool|byte|char|float(32|64)|u?int(8|16|32|64)|string)\b")
_FIELD = re.compile(
    r"(?P<type>string<=\d+|[A-Za-z0-9_/]+)(?:\[(?P<count>\d*|<=\d+)\])?"
    r"[ \t]+(?P<name>[A-Za-z][A-Za-z0-9_]*)(?:[ \t]+\S.*)?"
)
_CONSTANT = re.compile(r"(?P<type>[a-z0-9]+)[ \t]+(?P<name>[A-Z][A-Z0-9_]*)[ \t]*=[ \t]*\S.*")
_LOWER = re.compile(r"[a-z][a-z0-9_]*")
_MIXED = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
_UPPER = re.compile(r"[A-Z][A-Z0-9_]*")
_WORD = re.compile(r"[A-Za-z0-9_]+")


def _snake(word: str, first: re.Pattern) -> bool:
    """``word`` is ``first`` with single underscores between letters or digits."""
    return bool(first.fullmatch(word)) and "__" not in word and not word.endswith("_")


def _is_constant(line: str) -> bool:
    m = _CONSTANT.fullmatch(line)
    return bool(m and _BASE.fullmatch(m["type"]) and _snake(m["name"], _UPPER))


_HEADER = re.compile(r"MSG: ([A-Za-z0-9/_]+)[ \t]*")
_SEPARATOR = "=" * 80
_NAMED = {
    "time": "builtin_interfaces/msg/Time",
    "duration": "builtin_interfaces/msg/Duration",
    "Header": "std_msgs/msg/Header",
}


def _full(name: str) -> str:
    """``pkg/Name`` -> ``pkg/msg/Name`` (rosbags' normalisation of a ``MSG:`` name)."""
    parent, _, last = name.rpartition("/")
    if parent.rpartition("/")[2] in ("msg", "action"):
        return name
    return f"{parent}/msg/{last}" if parent else f"msg/{last}"


def _named(owner: str, name: str) -> str:
    """A field's message type as a full name, resolved against its owner as rosbags does."""
    name = _NAMED.get(name, name)
    if "/" not in name:
        return owner.rpartition("/")[0] + "/" + name
    if "/msg/" in name or "/action/" in name:
        return name
    parent, _, last = name.rpartition("/")
    return f"{parent}/msg/{last}"


def _type_base(owner: str, typ: str) -> str | None:
    """A field type as the fast path keeps it, or None when rosbags must judge it."""
    if typ.startswith("string<=") or typ == "string":
        return "string"
    if typ in PRIM:
        return typ
    if _BASE.match(typ):
        return None  # "int32/Foo": rosbags takes the base type and then fails
    *packages, name = typ.split("/")
    if not _snake(name, _MIXED) or not all(_snake(p, _LOWER) for p in packages):
        return None
    return _named(owner, typ)


def _msg_fields(owner: str, lines: list[str]) -> list[Field] | None:
    out = []
    for raw in lines:
        line = raw.split("#", 1)[0].strip()
        if not line or _is_constant(line):
            continue
        m = _FIELD.fullmatch(line)
        base = None if m is None else _type_base(owner, m["type"])
        if base is None:
            return None
        count, name = m["count"], m["name"]
        if name == "structure_needs_at_least_one_member":
            continue
        array = None if count is None else "fixed" if count.isdigit() else "seq"
        out.append(Field(name, base, array, int(count) if array == "fixed" else 0))
    return out


def _msg_types(text: str, root: str) -> Defs | None:
    """The field lists of a ``.msg`` text (``ros2msg`` or ``ros1msg``, with its ``MSG:``
    dependencies) in the plain forms rosbags' parser reads; None for anything else (quotes,
    annotations, a line it does not know), which then goes to rosbags."""
    if "'" in text or '"' in text or "@" in text or "\r" in text:
        return None
    lines = text.split("\n")
    sections: list[tuple[str, list[str]]] = [(root, [])]
    i = 0
    while i < len(lines):
        if lines[i] == _SEPARATOR:
            head = _HEADER.fullmatch(lines[i + 1]) if i + 1 < len(lines) else None
            if head is None:
                return None
            sections.append((head[1], []))
            i += 2
            continue
        sections[-1][1].append(lines[i])
        i += 1
    defs: Defs = {}
    for name, body in sections:
        if not all(_WORD.fullmatch(part) for part in name.split("/")):
            return None  # "pkg//Name", "pkg/Name/": rosbags' path rules decide
        full = _full(name)
        fields = _msg_fields(full, body)
        if fields is None:
            return None
        defs[full] = fields
    return defs


def _definitions(msgtype: str, encoding: str, text: str, serialization: str) -> Defs:
    """Field lists of a schema: plain ``.msg`` texts read here, the rest by rosbags."""
    root = norm_type(msgtype)
    if text.strip() and encoding not in ("ros2idl", "omgidl"):
        defs = _msg_types(text, root)
        if defs is not None:
            return _with_time(defs)
    # lazy: rosbags' type system costs ~15 ms at import; the plain .msg texts of most
    # logs are read above without it
    from rosbags.typesys import get_types_from_msg

    if text.strip():
        if encoding in ("ros2idl", "omgidl"):
            typesdict = _idl_types(text)
        else:
            typesdict = get_types_from_msg(text, root)
    else:
        from rosbags.typesys import Stores, get_typestore  # lazy, as above

        store = get_typestore(Stores.ROS1_NOETIC if serialization == "ros1" else Stores.ROS2_HUMBLE)
        if root not in store.fielddefs:
            raise LogError(
                f"Expected a message definition for {msgtype} (the bag stores none "
                f"and rosbags does not know the type), got none"
            )
        typesdict = store.fielddefs
    return _convert(typesdict)


@lru_cache(maxsize=64)
def _parse(msgtype: str, encoding: str, text: str, serialization: str) -> tuple[Defs, str]:
    root = norm_type(msgtype)
    if len(text.encode("utf-8", "surrogatepass")) > MAX_SCHEMA_BYTES:
        raise LogError(
            f"Expected a message definition of at most {MAX_SCHEMA_BYTES} bytes for "
            f"{msgtype}, got {len(text)} characters"
        )
    defs = _definitions(msgtype, encoding, text, serialization)
    if root not in defs:
        raise LogError(
            f"Expected the definition of {msgtype} in its schema, got only "
            f"{', '.join(sorted(defs)[:4]) or 'nothing'}"
        )
    _check_depth(defs, root)
    return defs, root


def definitions(conn: Conn) -> tuple[Defs, str]:
    """Field lists of ``conn``'s message type and its dependencies, and the root type name.

    Raises
    ------
    LogError
        The schema is corrupt, too large, too deep or self-containing (names the topic).
    """
    try:
        return _parse(conn.msgtype, conn.schema_encoding, conn.schema_text, conn.encoding)
    except LogError as exc:
        raise LogError(f"{conn.topic}: {exc}") from None
    except RecursionError:
        raise LogError(
            f"Expected a readable {conn.schema_encoding or 'message'} definition of "
            f"{conn.msgtype} on {conn.topic}, got nesting too deep"
        ) from None
    except Exception as exc:
        msg = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise LogError(
            f"Expected a readable {conn.schema_encoding or 'message'} definition of "
            f"{conn.msgtype} on {conn.topic}, got {type(exc).__name__}: {msg}"
        ) from None


def typestore_for(conn: Conn):
    """A rosbags type store holding ``conn``'s types (for the per-message fallback)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # lazy, as above

    root = norm_type(conn.msgtype)
    if not conn.schema_text.strip():
        return get_typestore(
            Stores.ROS1_NOETIC if conn.encoding == "ros1" else Stores.ROS2_HUMBLE
        ), root
    store = get_typestore(Stores.EMPTY)
    if conn.schema_encoding in ("ros2idl", "omgidl"):
        types = _idl_types(conn.schema_text)
    else:
        types = get_types_from_msg(conn.schema_text, root)
    base = get_typestore(Stores.ROS2_HUMBLE)
    for builtin in ("builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration"):
        types.setdefault(builtin, base.fielddefs[builtin])
    store.register(types)
    return store, root
