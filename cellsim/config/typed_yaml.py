"""Load YAML into typed dataclasses, with errors that name the file, line and key.

Scenario files follow Drake's "typed dataclass config" idiom: a tree of plain
``@dataclass`` classes is the schema, and a YAML document fills it in.  Drake's
own ``yaml_load_typed`` converts the data without keeping where it came from, so
when something is wrong the user learns *what* but not *where* (no line
numbers).  This module does the same job with the position kept: it composes
the YAML node tree itself (which also lets it reject duplicate keys, which
PyYAML silently accepts), records the line of every key and list item, and
converts the data field by field.  Every problem becomes one :class:`ConfigError` whose text is a single actionable line::

    scenarios/x.yaml:12: entities.operator.waypoints.cell.wait: expected a number, got 'abc'

The module is generic: it knows dataclasses, ``float``/``int``/``bool``/``str``,
``X | None``, ``list``/``dict``/``tuple``, string enums, ``Literal`` and
unions of dataclasses told apart by a ``kind: Literal["..."]`` field.  It knows
nothing about scenarios.  ``__post_init__`` checks may raise :class:`FieldError`
(reported at the field's line) or any ``ValueError`` (reported at the mapping).
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import functools
import math
import os
import types
import typing
from dataclasses import dataclass
from typing import Any, Callable, Generic, TypeVar

import yaml

__all__ = [
    "ConfigError",
    "FieldError",
    "Range",
    "range_of",
    "type_at",
    "suggest",
    "Loaded",
    "apply_override",
    "apply_overrides",
    "dump_yaml",
    "from_data",
    "load_file",
    "load_text",
    "to_data",
]

T = TypeVar("T")

# The C loader is much faster and reports the same marks (0-based line numbers).
_BaseLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


# The C emitter writes the same YAML several times faster (a campaign writes one per run).
_Dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


class _Loader(_BaseLoader):
    """SafeLoader with YAML 1.2 booleans: only true/false are booleans.

    YAML 1.1 also reads on/off/yes/no as booleans, which would turn the activity
    value ``off`` (and a key ``on:``) into ``False``; cell vocabularies need them as words.
    """


_Loader.yaml_implicit_resolvers = {
    first: [(tag, regex) for tag, regex in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in _BaseLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:bool",
    __import__("re").compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
    list("tTfF"),
)
_MERGE_TAG = "tag:yaml.org,2002:merge"
REPLACE_TAG = "!replace"
"""A mapping tagged ``!replace`` replaces its base's mapping whole instead of merging into it."""
_NoneType = type(None)


@dataclass(frozen=True)
class Range:
    """The valid range of a number: ``Annotated[float, Range(0, 10, lo_open=True, unit="s")]``.

    On a list or tuple of numbers (a position) it applies to each element. The
    converter checks it wherever the number comes from (a file, ``--set``), and
    ``cellsim modules`` shows it. Every float is also finite: NaN and infinities
    are refused everywhere, range or not.
    """

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    unit: str = ""

    def admits(self, x: float) -> bool:
        if self.lo is not None and (x <= self.lo if self.lo_open else x < self.lo):
            return False
        if self.hi is not None and (x >= self.hi if self.hi_open else x > self.hi):
            return False
        return True

    def __str__(self) -> str:
        def text(x) -> str:
            return str(x) if isinstance(x, int) else f"{x:g}"

        lo = "-inf" if self.lo is None else text(self.lo)
        hi = "inf" if self.hi is None else text(self.hi)
        interval = f"{'(' if self.lo_open or self.lo is None else '['}{lo}, {hi}{')' if self.hi_open or self.hi is None else ']'}"
        return f"{interval} {self.unit}".rstrip()


def range_of(tp: Any) -> Range | None:
    """The Range an ``Annotated`` type carries, if any."""
    if typing.get_origin(tp) is typing.Annotated:
        return next((m for m in typing.get_args(tp)[1:] if isinstance(m, Range)), None)
    return None


class FieldError(ValueError):
    """Raised by a dataclass ``__post_init__`` to blame one of its fields.

    ``field`` is relative to the dataclass and may be dotted (``"waypoints.bench"``).
    """

    def __init__(self, field: str, message: str):
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


MAX_MESSAGE = 1000
"""Longest error line, in characters."""


class ConfigError(Exception):
    """One configuration problem: ``source:line: key: problem``."""

    def __init__(self, source: str, line: int | None, key: str, problem: str):
        super().__init__(source, line, key, problem)  # args kept for pickling
        self.source = source
        self.line = line
        self.key = key
        self.problem = problem

    def __str__(self) -> str:
        where = self.source if self.line is None else f"{self.source}:{self.line}"
        text = f"{where}: {self.key}: {self.problem}" if self.key else f"{where}: {self.problem}"
        text = text.replace("\r", "\\r").replace("\n", "\\n")  # always one line
        return text if len(text) <= MAX_MESSAGE else text[: MAX_MESSAGE - 1] + "…"  # never a value dumped whole


@dataclass
class Loaded(Generic[T]):
    """A typed value together with where each of its keys was written.

    With a base file (``load_file(..., base_key="base")``), a key may have been
    written in a base rather than in ``source``: ``sources`` names that file, and
    :meth:`where` gives the file and line of any key.
    """

    value: T
    source: str
    lines: dict[str, int]
    sources: dict[str, str] = dataclasses.field(default_factory=dict)
    """Key -> the file it was written in, for keys not written in ``source``."""
    files: list[str] = dataclasses.field(default_factory=list)
    """Every file read: ``source`` first, then its bases."""

    def line_of(self, key: str) -> int | None:
        """Line of ``key``, or of its nearest written ancestor (``None`` if none)."""
        return _line_of(self.lines, key)

    def where(self, key: str) -> tuple[str, int | None]:
        """(file, line) where ``key``, or its nearest written ancestor, was written."""
        return _where(self.lines, self.sources, self.source, key)


# --------------------------------------------------------------------------- helpers


def _join(path: str, key: Any) -> str:
    return f"{path}.{key}" if path else str(key)


def _line_of(lines: dict[str, int], key: str) -> int | None:
    while True:
        if key in lines:
            return lines[key]
        if not key:
            return None
        key = key.rpartition(".")[0]


def _where(lines: dict[str, int], sources: dict[str, str], source: str, key: str) -> tuple[str, int | None]:
    while True:
        if key in lines:
            return sources.get(key, source), lines[key]
        if not key:
            return source, None
        key = key.rpartition(".")[0]


@functools.lru_cache(maxsize=None)
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, include_extras=True)


def _init_fields(cls: type) -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(cls) if f.init}


def _is_dataclass_type(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _shape_of(data: Any) -> str:
    """What a YAML value is: a list, a mapping or a scalar."""
    return "list" if isinstance(data, (list, tuple)) else "mapping" if isinstance(data, dict) else "scalar"


def _shape_of_type(tp: Any) -> str | None:
    """What a type takes: a list, a mapping or a scalar; None for a type that may take any (a union, Any)."""
    if typing.get_origin(tp) is typing.Annotated:
        return _shape_of_type(typing.get_args(tp)[0])
    origin = typing.get_origin(tp) or tp
    if origin in (list, tuple):
        return "list"
    if origin is dict or _is_dataclass_type(tp):
        return "mapping"
    if tp is Any or tp is object or _union_args(tp) is not None:
        return None
    return "scalar"


def _union_args(tp: Any) -> tuple[Any, ...] | None:
    """Members of a ``Union``/``X | Y`` type, or ``None`` if ``tp`` is not one."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return typing.get_args(tp)
    return None


def _kind_of(cls: type) -> Any:
    """The single ``Literal`` value of a dataclass's ``kind`` field, or ``None``."""
    tp = _hints(cls).get("kind")
    if typing.get_origin(tp) is typing.Literal and len(typing.get_args(tp)) == 1:
        return typing.get_args(tp)[0]
    return None


def _same(a: Any, b: Any) -> bool:
    """Equality that does not confuse ``True`` with ``1``."""
    return type(a) is type(b) and a == b


def suggest(word: str, options) -> str:
    """"; did you mean 'x'?" for the option closest to ``word``, or "" when none is close."""
    match = difflib.get_close_matches(word, list(options), n=1)
    return f"; did you mean '{match[0]}'?" if match else ""


def _type_name(tp: Any) -> str:
    names = {float: "a number", int: "an integer", bool: "true or false", str: "a string",
             _NoneType: "null", list: "a list", tuple: "a list", dict: "a mapping"}
    if tp in names:
        return names[tp]
    origin = typing.get_origin(tp)
    if origin in names:
        return names[origin]
    if _is_dataclass_type(tp):
        return "a mapping"
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return "one of: " + ", ".join(str(m.value) for m in tp)
    if origin is typing.Literal:
        return "one of: " + ", ".join(str(v) for v in typing.get_args(tp))
    return getattr(tp, "__name__", str(tp))


# --------------------------------------------------------------------------- YAML -> data


class _Composer:
    """Turns a composed YAML node tree into plain data, recording lines and texts."""

    def __init__(self, loader: Any, source: str):
        self.loader = loader
        self.source = source
        self.lines: dict[str, int] = {}
        self.texts: dict[str, str] = {}  # source text of scalars, for error messages
        self.done: dict[int, Any] = {}   # aliases: a node is converted once
        self.active: set[int] = set()    # nodes being converted: detects recursive aliases
        self.replace: set[str] = set()   # paths of mappings tagged !replace (not merged over a base)

    def error(self, node: yaml.Node, key: str, problem: str) -> ConfigError:
        return ConfigError(self.source, node.start_mark.line + 1, key, problem)

    def build(self, node: yaml.Node, path: str) -> Any:
        if id(node) in self.done:
            return self.done[id(node)]
        if id(node) in self.active:
            raise self.error(node, path, "recursive YAML alias")
        self.active.add(id(node))
        if isinstance(node, yaml.ScalarNode):
            result = self.scalar(node, path)
            self.texts[path] = node.value
        elif isinstance(node, yaml.SequenceNode):
            self._known_tag(node, path, "tag:yaml.org,2002:seq")  # (a list replaces its base's: !replace is moot)
            result = []
            for i, item in enumerate(node.value):
                self.lines[_join(path, i)] = item.start_mark.line + 1
                result.append(self.build(item, _join(path, i)))
        else:
            result = self.mapping(node, path)
        self.active.discard(id(node))
        self.done[id(node)] = result
        return result

    def scalar(self, node: yaml.ScalarNode, path: str) -> Any:
        try:
            return self.loader.construct_object(node, deep=True)
        except yaml.MarkedYAMLError as e:
            raise self.error(node, path, f"malformed YAML: {e.problem or e}") from None
        except Exception as e:  # e.g. an impossible date such as 2001-02-30
            raise self.error(node, path, f"malformed YAML: {e}") from None

    def _known_tag(self, node: yaml.Node, path: str, plain: str) -> None:
        """Refuse a tag this format does not know on a mapping or a list (a misspelt ``!replace`` would otherwise
        be ignored, and a mapping merged over its base's where it was meant to replace it)."""
        if node.tag not in (plain, REPLACE_TAG):
            close = difflib.get_close_matches(node.tag.lower(), [REPLACE_TAG], n=1, cutoff=0.6)
            hint = f" (did you mean '{REPLACE_TAG}'?)" if close else f" (the only one known here is '{REPLACE_TAG}')"
            raise self.error(node, path, f"unknown tag '{node.tag}'{hint}")

    def mapping(self, node: yaml.MappingNode, path: str) -> dict[Any, Any]:
        self._known_tag(node, path, "tag:yaml.org,2002:map")
        if node.tag == REPLACE_TAG:
            self.replace.add(path)
        merged: dict[Any, Any] = {}
        explicit: dict[Any, Any] = {}
        # Merge keys ("<<: *base") first, so that explicit keys and their lines win.
        for knode, vnode in node.value:
            if knode.tag != _MERGE_TAG:
                continue
            bases = vnode.value if isinstance(vnode, yaml.SequenceNode) else [vnode]
            for base in bases:
                if not isinstance(base, yaml.MappingNode):
                    raise self.error(base, path, "malformed YAML: '<<' merges only mappings")
                for k, v in self.build(base, path).items():
                    merged.setdefault(k, v)
        first_line: dict[Any, int] = {}
        for knode, vnode in node.value:
            if knode.tag == _MERGE_TAG:
                continue
            if not isinstance(knode, yaml.ScalarNode):
                raise self.error(knode, path, "mapping keys must be plain values")
            key = self.scalar(knode, path)
            kpath = _join(path, key)
            line = knode.start_mark.line + 1
            if key in first_line:
                raise ConfigError(self.source, line, kpath,
                                  f"duplicate key '{key}' (first given on line {first_line[key]})")
            first_line[key] = line
            self.lines[kpath] = line
            explicit[key] = self.build(vnode, kpath)
        merged.update(explicit)
        return merged


def parse_yaml(text: str, source: str = "<text>") -> Any:
    """A YAML document as plain data, read as scenario files are (``!replace`` known, unknown tags refused):
    ConfigError naming ``source`` and the line otherwise."""
    return _parse(text, source)[0]


def _parse(text: str, source: str) -> tuple[Any, dict[str, int], dict[str, str]]:
    data, lines, texts, _ = _parse_full(text, source)
    return data, lines, texts


MAX_DEPTH = 100
"""Deepest nesting of lists and mappings a file may have."""
MAX_NODES = 200_000
"""Most values a file may expand to, aliases counted as often as they are used."""


def _check_size(text: str, source: str) -> None:
    """Refuse, in bounded time and memory, a document too deep or that aliases expand too far.

    A first pass over the parser's events (libyaml's parser keeps its own stack,
    so depth costs no recursion) counts nesting and the expanded size of every
    anchor: 100 000 nested brackets, which would overflow the composer's stack,
    and a "billion laughs" of aliases of aliases are one error line each.
    """
    loader = _Loader(text)
    frames: list[list] = [[None, 0]]  # [anchor, expanded size] of each open collection
    sizes: dict[str, int] = {}
    try:
        while True:
            event = loader.get_event()
            if event is None or isinstance(event, yaml.StreamEndEvent):
                break
            if isinstance(event, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
                frames.append([event.anchor, 1])
                if len(frames) - 1 > MAX_DEPTH:
                    raise ConfigError(source, event.start_mark.line + 1, "",
                                      f"malformed YAML: nested deeper than {MAX_DEPTH} levels")
            elif isinstance(event, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
                anchor, size = frames.pop()
                if anchor is not None:
                    sizes[anchor] = size
                frames[-1][1] += size
            elif isinstance(event, yaml.ScalarEvent):
                if event.anchor is not None:
                    sizes[event.anchor] = 1
                frames[-1][1] += 1
            elif isinstance(event, yaml.AliasEvent):
                frames[-1][1] += sizes.get(event.anchor, 1)
            else:
                continue
            if frames[-1][1] > MAX_NODES:
                raise ConfigError(source, event.start_mark.line + 1, "",
                                  f"malformed YAML: expands to more than {MAX_NODES} values (aliases of aliases?)")
    except yaml.YAMLError as e:
        if "maximum nesting depth" in str(e):  # PyYAML >= 6.0.3 has a depth limit of its own: one message
            mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
            raise ConfigError(source, mark.line + 1 if mark else None, "",
                              f"malformed YAML: nested deeper than {MAX_DEPTH} levels") from None
        return  # the composer reports malformed YAML with its position
    finally:
        loader.dispose()


def _parse_full(text: str, source: str) -> tuple[Any, dict[str, int], dict[str, str], set[str]]:
    """(data, line of each key, source text of each scalar, paths of mappings tagged !replace)."""
    _check_size(text, source)
    loader = _Loader(text)
    try:
        try:
            node = loader.get_single_node()
        except yaml.MarkedYAMLError as e:
            mark = e.problem_mark or e.context_mark
            what = "; ".join(p for p in (e.context, e.problem) if p) or str(e)
            raise ConfigError(source, mark.line + 1 if mark else None, "",
                              f"malformed YAML: {what}") from None
        except yaml.reader.ReaderError as e:  # e.g. a control character; no mark, a position
            line = text.count("\n", 0, e.position) + 1 if isinstance(e.position, int) else None
            raise ConfigError(source, line, "", f"malformed YAML: unacceptable character "
                              f"#x{ord(e.character) if isinstance(e.character, str) else e.character:04x}: "
                              f"{e.reason}") from None
        except yaml.YAMLError as e:
            raise ConfigError(source, None, "", f"malformed YAML: {e}") from None
        if node is None:
            raise ConfigError(source, 1, "", "empty document (expected a mapping)")
        if not isinstance(node, yaml.MappingNode):
            kind = "a list" if isinstance(node, yaml.SequenceNode) else f"'{node.value}'"
            raise ConfigError(source, node.start_mark.line + 1, "",
                              f"expected a mapping at the top level, got {kind}")
        composer = _Composer(loader, source)
        composer.lines[""] = node.start_mark.line + 1
        data = composer.build(node, "")
        return data, composer.lines, composer.texts, composer.replace
    finally:
        loader.dispose()


# --------------------------------------------------------------------------- data -> typed


class _Converter:
    """Converts plain data to a type, raising :class:`ConfigError` at the right line."""

    def __init__(self, source: str, lines: dict[str, int] | None = None,
                 texts: dict[str, str] | None = None, sources: dict[str, str] | None = None):
        self.source = source
        self.lines = lines or {}
        self.texts = texts or {}
        self.sources = sources or {}

    def error(self, path: str, problem: str) -> ConfigError:
        return ConfigError(*_where(self.lines, self.sources, self.source, path), path, problem)

    def describe(self, data: Any, path: str) -> str:
        if isinstance(data, dict):
            return "a mapping"
        if isinstance(data, (list, tuple)):
            return "a list"
        if data is None:
            return "null"
        if path in self.texts and not isinstance(data, str):
            text = self.texts[path]  # what the user wrote, e.g. 'no' rather than false
        elif isinstance(data, bool):
            text = str(data).lower()
        else:
            text = str(data.value if isinstance(data, enum.Enum) else data)
        text = text.replace("\r", "\\r").replace("\n", "\\n")
        return f"'{text[:60]}...'" if len(text) > 60 else f"'{text}'"

    def expected(self, tp: Any, data: Any, path: str, hint: str = "") -> ConfigError:
        return self.error(path, f"expected {_type_name(tp)}, got {self.describe(data, path)}{hint}")

    def convert(self, tp: Any, data: Any, path: str) -> Any:
        if tp is Any or tp is object:
            return data
        if typing.get_origin(tp) is typing.Annotated:
            base, *extras = typing.get_args(tp)
            value = self.convert(base, data, path)
            for extra in extras:
                if isinstance(extra, Range):
                    self.check_range(extra, value, path)
            return value
        if hasattr(tp, "__kind_config__"):
            return self.registered_kind(tp, data, path)
        members = _union_args(tp)
        if members is not None:
            return self.union(members, data, path)
        origin = typing.get_origin(tp)
        if origin is typing.Literal:
            choices = typing.get_args(tp)
            for choice in choices:
                if _same(choice, data):
                    return choice
            raise self.error(path, f"{self.describe(data, path)} is not one of: "
                             + ", ".join(str(c) for c in choices))
        if isinstance(tp, type) and issubclass(tp, enum.Enum):
            return self.enum(tp, data, path)
        if _is_dataclass_type(tp):
            return self.dataclass(tp, data, path)
        if tp in (list, tuple, dict) or origin in (list, tuple, dict):
            return self.container(tp, origin or tp, data, path)
        return self.scalar(tp, data, path)

    def scalar(self, tp: Any, data: Any, path: str) -> Any:
        if tp is bool:
            if isinstance(data, bool):
                return data
        elif tp is int:
            if isinstance(data, int) and not isinstance(data, bool):
                return data
        elif tp is float:
            if isinstance(data, (int, float)) and not isinstance(data, bool):
                try:
                    value = float(data)
                except OverflowError:
                    raise self.error(path, f"number too large: {self.describe(data, path)}") from None
                if not math.isfinite(value):
                    raise self.error(path, f"expected a finite number, got {self.describe(data, path)}")
                return value
            if isinstance(data, str) and data.strip().lower().lstrip("+-") in ("nan", "inf", "infinity"):
                raise self.error(path, f"expected a finite number, got {self.describe(data, path)}")
            if isinstance(data, str) and "e" in data.lower():
                try:
                    float(data)
                except ValueError:
                    pass
                else:  # PyYAML (YAML 1.1) wants a dot and a signed exponent
                    raise self.expected(tp, data, path, " (YAML reads it as text; write e.g. 1.0e+3)")
        elif tp is str:
            if isinstance(data, str):
                return data
            if data is not None and not isinstance(data, (dict, list, tuple)):
                raise self.expected(tp, data, path, " (put it in quotes)")
        elif tp is _NoneType:
            if data is None:
                return None
        elif isinstance(tp, type) and isinstance(data, tp):
            return data
        elif not isinstance(tp, type):
            raise TypeError(f"typed_yaml: unsupported type {tp!r} at '{path}'")
        raise self.expected(tp, data, path)

    def enum(self, tp: type[enum.Enum], data: Any, path: str) -> enum.Enum:
        if isinstance(data, tp):
            return data
        for member in tp:
            if _same(member.value, data):
                return member
        raise self.error(path, f"{self.describe(data, path)} is not one of: "
                         + ", ".join(str(m.value) for m in tp))

    def container(self, tp: Any, origin: type, data: Any, path: str) -> Any:
        args = typing.get_args(tp)
        if origin is dict:
            if not isinstance(data, dict):
                raise self.expected(dict, data, path)
            ktype, vtype = args or (Any, Any)
            out = {}
            for key, value in data.items():
                kpath = _join(path, key)
                if ktype is str and not isinstance(key, str):
                    raise self.error(kpath, f"keys must be strings, got {self.describe(key, '')}"
                                     " (put it in quotes)")
                out[self.convert(ktype, key, kpath)] = self.convert(vtype, value, kpath)
            return out
        if not isinstance(data, (list, tuple)):
            raise self.expected(list, data, path)
        if origin is list:
            item = args[0] if args else Any
            return [self.convert(item, x, _join(path, i)) for i, x in enumerate(data)]
        if not args:
            return tuple(data)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(self.convert(args[0], x, _join(path, i)) for i, x in enumerate(data))
        if len(data) != len(args):
            raise self.error(path, f"expected a list of {len(args)} items, got {len(data)}")
        return tuple(self.convert(a, x, _join(path, i)) for i, (a, x) in enumerate(zip(args, data)))

    def union(self, members: tuple[Any, ...], data: Any, path: str) -> Any:
        if data is None and _NoneType in members:
            return None
        arms = [m for m in members if m is not _NoneType]
        if len(arms) == 1:
            return self.convert(arms[0], data, path)
        if all(_is_dataclass_type(a) and _kind_of(a) is not None for a in arms):
            return self.by_kind(arms, data, path)
        fitting = []  # each member whose shape (a list, a mapping, a scalar) the value has, with why it refused it
        for arm in arms:  # general union: first member that accepts the value wins
            try:
                return self.convert(arm, data, path)
            except ConfigError as refused:
                if _shape_of_type(arm) in (_shape_of(data), None):
                    fitting.append(refused)
        if len(fitting) == 1:  # the value is meant as that member: say what is wrong inside it (``home.2``)
            raise fitting[0]
        names = " or ".join(_type_name(m) for m in members)
        raise self.error(path, f"expected {names}, got {self.describe(data, path)}")

    def by_kind(self, arms: list[type], data: Any, path: str) -> Any:
        kinds = {_kind_of(a): a for a in arms}
        known = ", ".join(str(k) for k in kinds)
        if isinstance(data, tuple(arms)):  # an instance inside plain data
            return self.dataclass(type(data), data, path)
        if not isinstance(data, dict):
            raise self.expected(dict, data, path)
        if "kind" not in data:
            raise self.error(path, f"missing required key 'kind' (one of: {known})")
        kind = data["kind"]
        for value, cls in kinds.items():
            if _same(value, kind):
                return self.dataclass(cls, data, path)
        kpath = _join(path, "kind")
        hint = suggest(kind, [str(k) for k in kinds]) if isinstance(kind, str) else ""
        raise self.error(kpath, f"unknown kind {self.describe(kind, kpath)} "
                         f"(expected one of: {known}){hint}")

    def check_range(self, valid: Range, value: Any, path: str) -> None:
        items = value if isinstance(value, (list, tuple)) else [value]
        for i, x in enumerate(items):
            if isinstance(x, (int, float)) and not isinstance(x, bool) and not valid.admits(x):
                where = _join(path, i) if isinstance(value, (list, tuple)) else path
                raise self.error(where, f"{self.describe(x, where)} is out of range: must be in {valid}")

    def registered_kind(self, marker: Any, data: Any, path: str) -> Any:
        """A config whose dataclass a registry picks by its ``kind`` (plug-in module kinds).

        ``marker.__kind_config__(name)`` returns the dataclass or raises a
        LookupError whose text is the problem; ``marker.__kind_names__()`` lists
        the kinds known, for the error message.
        """
        if dataclasses.is_dataclass(data) and not isinstance(data, type):
            data = to_data(data)
        if not isinstance(data, dict):
            raise self.expected(dict, data, path)
        if "kind" not in data:
            raise self.error(path, f"missing required key 'kind' (one of: {', '.join(marker.__kind_names__())})")
        kind, kpath = data["kind"], _join(path, "kind")
        if not isinstance(kind, str):
            raise self.error(kpath, f"expected a kind name, got {self.describe(kind, kpath)}")
        try:
            cls = marker.__kind_config__(kind)
        except LookupError as e:
            known = marker.__kind_names__()
            hint = suggest(kind, known) if str(e).startswith("unknown kind") else ""
            detail = f" (expected one of: {', '.join(known)})" if str(e).startswith("unknown kind") else ""
            raise self.error(kpath, f"{e.args[0] if e.args else e}{detail}{hint}") from None
        return self.dataclass(cls, data, path)

    def dataclass(self, cls: type, data: Any, path: str) -> Any:
        if isinstance(data, cls):
            data = to_data(data)  # re-check an instance given in plain data
        if not isinstance(data, dict):
            raise self.expected(cls, data, path)
        fields, hints = _init_fields(cls), _hints(cls)
        kwargs = {}
        for key, value in data.items():
            kpath = _join(path, key)
            if key not in fields:
                names = list(fields)
                raise self.error(kpath, f"unknown key '{key}' (expected one of: {', '.join(names)})"
                                 + suggest(str(key), names))
            kwargs[key] = self.convert(hints[key], value, kpath)
        for name, f in fields.items():
            if (name not in kwargs and f.default is dataclasses.MISSING
                    and f.default_factory is dataclasses.MISSING):
                raise self.error(path, f"missing required key '{name}'")
        try:
            return cls(**kwargs)
        except FieldError as e:
            raise self.error(_join(path, e.field), e.message) from None
        except ValueError as e:
            raise self.error(path, str(e)) from None


# --------------------------------------------------------------------------- public API


def load_text(schema: type[T], text: str, source: str = "<text>") -> Loaded[T]:
    """Parse ``text`` as YAML and convert it to ``schema``; raises :class:`ConfigError`."""
    try:
        data, lines, texts = _parse(text, source)
        value = _Converter(source, lines, texts).convert(schema, data, "")
    except RecursionError:
        raise ConfigError(source, None, "", "malformed YAML: nested too deeply") from None
    return Loaded(value=value, source=source, lines=lines)


def load_file(schema: type[T], path: str | os.PathLike, *, base_key: str | None = None) -> Loaded[T]:
    """Read a UTF-8 YAML file and convert it to ``schema``; raises :class:`ConfigError`.

    With ``base_key``, a top-level ``base_key: other.yaml`` (relative to the file)
    names a base: the file is the base with its own keys merged in. Mappings
    merge key by key, recursively, unless tagged ``!replace``; any other value
    (a list, a number) replaces the base's. Bases may have bases; a cycle is an error. Every key keeps the
    file and line where it was written, for errors and for paths relative to it.
    """
    source = os.fspath(path)
    if base_key is None:
        return load_text(schema, _read(source), source)
    try:
        data, lines, texts, sources, files = _parse_with_bases(source, base_key, [])
        value = _Converter(source, lines, texts, sources).convert(schema, data, "")
    except RecursionError:
        raise ConfigError(source, None, "", "malformed YAML: nested too deeply") from None
    return Loaded(value=value, source=source, lines=lines, sources=sources, files=files)


MAX_FILE_CHARS = 10_000_000
"""Longest configuration file, in characters (a device such as /dev/zero never ends)."""


def _read(source: str) -> str:
    try:
        with open(source, encoding="utf-8") as f:
            text = f.read(MAX_FILE_CHARS + 1)
    except UnicodeDecodeError:  # said at the line it is on, not at a byte offset in a buffer
        with open(source, "rb") as f:
            data = f.read(4 * MAX_FILE_CHARS + 4)
        try:
            data.decode("utf-8")
            at = len(data)  # (only cut off at the end: said there)
        except UnicodeDecodeError as e:
            at = e.start
        raise ConfigError(source, data[:at].count(b"\n") + 1, "", "not UTF-8 text"
                          + (f": byte 0x{data[at]:02x} cannot be read" if at < len(data) else "")
                          + " (save the file as UTF-8)") from None
    except OSError as e:
        raise ConfigError(source, None, "", f"cannot read file: {e.strerror or e}") from None
    if len(text) > MAX_FILE_CHARS:
        raise ConfigError(source, None, "", f"file too long: more than {MAX_FILE_CHARS:,} characters")
    return text


def _parse_with_bases(source: str, base_key: str, chain: list[str]):
    """(data, lines, texts, sources, files) of ``source`` merged over its bases."""
    data, lines, texts, replace = _parse_full(_read(source), source)
    files = [source]
    if base_key not in data:
        return data, lines, texts, {}, files
    base = data.pop(base_key)
    if not isinstance(base, str) or not base:
        raise ConfigError(source, lines.get(base_key), base_key, "expected the path of a base file, relative to this one")
    base_path = os.path.normpath(os.path.join(os.path.dirname(source), base))
    here = os.path.realpath(source)
    if os.path.realpath(base_path) in chain + [here]:
        raise ConfigError(source, lines.get(base_key), base_key, f"{base} is a base of itself (bases form a cycle)")
    if os.path.isdir(base_path):
        raise ConfigError(source, lines.get(base_key), base_key, f"{base} is a folder, not a base file ({base_path})")
    if not os.path.isfile(base_path):
        raise ConfigError(source, lines.get(base_key), base_key, f"file not found: {base} (looked for {base_path})")
    lines.pop(base_key, None)
    texts.pop(base_key, None)
    b_data, b_lines, b_texts, b_sources, b_files = _parse_with_bases(base_path, base_key, chain + [here])
    replaced = _replaced_paths(b_data, data, "", replace)

    def keep(key: str) -> bool:
        return not any(key == p or key.startswith(p + ".") for p in replaced)

    merged_lines = {k: v for k, v in b_lines.items() if keep(k) and k != ""}
    sources = {k: b_sources.get(k, base_path) for k in merged_lines}
    merged_texts = {k: v for k, v in b_texts.items() if keep(k)}
    merged_lines.update(lines)
    merged_texts.update(texts)
    for key in lines:
        sources.pop(key, None)
    return _deep_merge(b_data, data, "", replace), merged_lines, merged_texts, sources, files + b_files


def _replaced_paths(base: Any, over: Any, path: str, replace: set[str]) -> list[str]:
    """Keys whose base value the override replaces whole (so the base's sub-keys go)."""
    out = []
    for key, value in over.items():
        kpath = _join(path, key)
        if isinstance(value, dict) and isinstance(base.get(key), dict) and kpath not in replace:
            out += _replaced_paths(base[key], value, kpath, replace)
        elif key in base:
            out.append(kpath)
    return out


def _deep_merge(base: Any, over: Any, path: str, replace: set[str]) -> Any:
    merged = dict(base)
    for key, value in over.items():
        kpath = _join(path, key)
        if isinstance(value, dict) and isinstance(merged.get(key), dict) and kpath not in replace:
            merged[key] = _deep_merge(merged[key], value, kpath, replace)
        else:
            merged[key] = value
    return merged


def from_data(schema: type[T], data: Any, source: str = "<data>") -> T:
    """Convert plain Python data (dicts, lists, scalars) to ``schema``; errors carry no line."""
    return _Converter(source).convert(schema, data, "")


def to_data(value: Any) -> Any:
    """Plain data for ``value``: dataclasses become dicts of all their ``init`` fields in
    declaration order (defaults included), enums their value, tuples lists."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_data(getattr(value, f.name))
                for f in dataclasses.fields(value) if f.init}
    if isinstance(value, enum.Enum):
        return to_data(value.value)
    if isinstance(value, dict):
        return {to_data(k): to_data(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_data(v) for v in value]
    for plain in (bool, int, float, str):  # e.g. numpy scalars, which safe_dump rejects
        if isinstance(value, plain):
            return plain(value)
    return value


def dump_yaml(value: Any, header: str | None = None) -> str:
    """The fully resolved YAML for ``value``, optionally preceded by ``# `` comment lines."""
    text = yaml.dump(to_data(value), Dumper=_Dumper, sort_keys=False, default_flow_style=None)
    if header is None:
        return text
    comment = "".join(f"# {line}".rstrip() + "\n" for line in header.splitlines())
    return comment + text


def _element_type(tp: Any, key: Any) -> Any:
    """Declared type of ``tp``'s element ``key`` (dict value, list item, tuple slot)."""
    if typing.get_origin(tp) is typing.Annotated:  # a range on a list applies to its items
        base, *extras = typing.get_args(tp)
        item = _element_type(base, key)
        return typing.Annotated[(item, *extras)] if extras and item is not Any else item
    members = _union_args(tp)
    if members is not None:  # an optional value's elements: those of the value (ranges kept)
        arms = [m for m in members if m is not _NoneType]
        return _element_type(arms[0], key) if len(arms) == 1 else Any
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is dict and args:
        return args[1]
    if origin is list and args:
        return args[0]
    if origin is tuple and args:
        return args[0] if len(args) == 2 and args[1] is Ellipsis else args[key]
    return Any


def _locate(root: Any, parts: list[str]) -> tuple[list[Any], Any]:
    """Resolve ``parts`` through the typed ``root``: the real keys and the target's type."""
    value, tp, keys = root, type(root), []
    for i, part in enumerate(parts):
        here = ".".join(parts[:i])
        full = ".".join(parts)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            options = list(_init_fields(type(value)))
            key = part if part in options else None
            if key is not None:
                tp, value = _hints(type(value))[key], getattr(value, key)
        elif isinstance(value, dict):
            options = [str(k) for k in value]
            key = next((k for k in value if str(k) == part), None)
            if key is not None:
                tp, value = _element_type(tp, key), value[key]
        elif isinstance(value, (list, tuple)):
            options = []
            key = int(part) if part.isascii() and part.isdigit() and int(part) < len(value) else None
            if key is None:
                raise ConfigError("--set", None, full, "no such configuration point "
                                  f"('{here}' is a list of {len(value)} items, indexed from 0)")
            tp, value = _element_type(tp, key), value[key]
        else:
            what = "not set (null)" if value is None else "a single value, not a mapping"
            raise ConfigError("--set", None, full, f"no such configuration point ('{here}' is {what})")
        if key is None:  # suggest by leaf name: shared prefixes would make everything "close"
            match = difflib.get_close_matches(part, options, n=1)
            hint = f"; did you mean '{_join(here, match[0])}'?" if match else ""
            if not hint:
                hint = f" (options at '{here or 'top level'}': {', '.join(options[:12]) or 'none'})"
            raise ConfigError("--set", None, full, "no such configuration point" + hint)
        keys.append(key)
    return keys, tp


def type_at(root: Any, parts: list[str]) -> Any:
    """The declared type of the value at ``parts`` below a typed value (ConfigError if none)."""
    return _locate(root, parts)[1]


def override_value(value: object) -> str:
    """``value`` written as the right-hand side of a ``--set`` (YAML): a string or bool as JSON (quoted, lower case),
    a number as Python writes it. The one spelling of a sampled value, at load time and in every run."""
    import json

    return json.dumps(value) if isinstance(value, (bool, str)) else repr(value)


def apply_override(loaded: Loaded[T], assignment: str,
                   resolve: Callable[[list[str]], list[str]] | None = None) -> None:
    """Apply ``"dotted.path=value"`` (value parsed as YAML) to ``loaded.value``.

    ``resolve`` may rewrite the path components first (shortcuts).  The whole value
    is then rebuilt so that every ``__post_init__`` check runs again.  On any error a
    :class:`ConfigError` with source ``"--set"`` is raised and ``loaded.value`` is
    left unchanged.
    """
    apply_overrides(loaded, [assignment], resolve)


def apply_overrides(loaded: Loaded[T], assignments: list[str],
                    resolve: Callable[[list[str]], list[str]] | None = None) -> None:
    """Apply several overrides, with the result and errors of applying them one by one.

    The value is rebuilt once for all of them (a campaign run sets several); when
    anything fails, they are applied one at a time, so the error names the one at
    fault and a path that only exists after an earlier override still resolves.
    """
    if len(assignments) > 1:
        try:
            data = to_data(loaded.value)
            for assignment in assignments:
                keys, new_value, _ = _parse_override(loaded.value, assignment, resolve)
                _set_in(data, keys, new_value)
            loaded.value = from_data(type(loaded.value), data, source="--set")
            return
        except ConfigError:
            pass
    for assignment in assignments:
        keys, new_value, full = _parse_override(loaded.value, assignment, resolve)
        data = to_data(loaded.value)
        _set_in(data, keys, new_value)
        try:
            loaded.value = from_data(type(loaded.value), data, source="--set")
        except ConfigError as e:  # a check elsewhere in the tree now fails
            problem = e.problem if e.key == full else f"{e.problem} (at {e.key or 'top level'})"
            raise ConfigError("--set", None, full, problem) from None


def _set_in(data: Any, keys: list[Any], value: Any) -> None:
    target = data
    for key in keys[:-1]:
        target = target[to_data(key)]
    target[to_data(keys[-1])] = to_data(value)


def _parse_override(value: Any, assignment: str, resolve) -> tuple[list[Any], Any, str]:
    """The resolved keys of an override, its value converted to the declared type, its path."""
    path_text, sep, value_text = assignment.partition("=")
    parts = [p.strip() for p in path_text.split(".")]
    if not sep or not all(parts):
        raise ConfigError("--set", None, path_text.strip(),
                          f"malformed override '{assignment}' (expected dotted.path=value)")
    if resolve is not None:
        parts = list(resolve(parts))
    full = ".".join(str(p) for p in parts)
    if not parts:
        raise ConfigError("--set", None, "", f"malformed override '{assignment}' (empty path)")
    try:
        _check_size(value_text, "--set")  # an alias bomb or deep nesting: bounded, as in a file
    except ConfigError as e:
        raise ConfigError("--set", None, full, e.problem.replace("malformed YAML", "malformed value")) from None
    # read as a file reads a value (YAML 1.2: 'off' and 'yes' are words, as in the scenario file; PyYAML's own
    # reading made them booleans on the command line only): the value indented under a key of its own
    wrapped = "v:\n" + "\n".join("  " + line for line in value_text.splitlines())
    try:
        raw = parse_yaml(wrapped, "--set")["v"]
    except RecursionError:
        raise ConfigError("--set", None, full, "malformed value: nested too deeply") from None
    except ConfigError as e:
        raise ConfigError("--set", None, full, f"malformed value '{value_text.strip()}': "
                          f"{e.problem.removeprefix('malformed YAML: ')}") from None
    keys, tp = _locate(value, [str(p) for p in parts])
    return keys, _Converter("--set").convert(tp, raw, full), full
