"""What ``cellsim modules`` shows: every module kind, described from the code's own declarations.

A kind's parameters are its config dataclass's fields (type, default, and the
docstring written under the field), its channels and physical-twin fields are
what its :class:`~cellsim.kind.ModuleKind` declares. Nothing here is written
twice, so the listing cannot drift from the code.
"""

from __future__ import annotations

import ast
import dataclasses
import enum
import functools
import inspect
import textwrap
import typing
from dataclasses import dataclass

from cellsim import registry


@dataclass(frozen=True)
class Parameter:
    name: str
    type: str
    default: str
    range: str
    doc: str


def range_text(tp) -> str:
    """The valid range of a numeric type, or of the numbers inside a list, tuple or mapping.

    A number with no declared range is still ``finite`` (NaN and infinities are refused everywhere).
    """
    from cellsim.config.typed_yaml import range_of

    found = range_of(tp)
    if found is not None:
        return str(found)
    if tp is float:
        return "finite"
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Annotated:
        return range_text(args[0])
    for arg in reversed(args):  # a mapping's values, a list's items, an optional's value
        text = range_text(arg)
        if text:
            return text
    return ""


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """The docstrings written under a dataclass's fields (``x: float = 1.0`` then ``\"\"\"...\"\"\"``)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for node, following in zip(body, body[1:]):
            if (
                isinstance(node, ast.AnnAssign)
                and isinstance(node.target, ast.Name)
                and isinstance(following, ast.Expr)
                and isinstance(following.value, ast.Constant)
                and isinstance(following.value.value, str)
            ):
                docs[node.target.id] = " ".join(following.value.value.split())
    return docs


def type_name(tp) -> str:
    """A field's type as a user writes it in YAML."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Annotated:
        return type_name(args[0])
    if origin is typing.Literal:
        return " | ".join(repr(a) if not isinstance(a, str) else a for a in args)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " | ".join("null" if a is type(None) else type_name(a) for a in args)
    if origin is list:
        return f"list of {type_name(args[0])}" if args else "list"
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {type_name(args[0])}"
        return f"[{', '.join(type_name(a) for a in args)}]"
    if origin is dict:
        return f"mapping of {type_name(args[0])} to {type_name(args[1])}" if args else "mapping"
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return " | ".join(str(m.value) for m in tp)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return tp.__name__
    return {float: "number", int: "integer", bool: "true/false", str: "text"}.get(tp, getattr(tp, "__name__", str(tp)))


def parameters(config: type, prefix: str = "") -> list[Parameter]:
    """Every parameter of a config, nested configs flattened (``twin.stale_after``, ``waypoints.<name>.wait``)."""
    hints = typing.get_type_hints(config, include_extras=True)
    docs = field_docs(config)
    out = []
    for f in dataclasses.fields(config):
        if not f.init or f.name == "kind":
            continue
        if f.default is not dataclasses.MISSING:
            default = _show(f.default)
        elif f.default_factory is not dataclasses.MISSING:
            default = _show(f.default_factory())
        else:
            default = "required"
        tp = hints[f.name]
        out.append(Parameter(prefix + f.name, type_name(tp), default, range_text(tp), docs.get(f.name, "")))
        nested, key = _nested(tp)
        if nested is not None:
            out += parameters(nested, f"{prefix}{f.name}.{key}")
    return out


def _nested(tp) -> tuple[type | None, str]:
    """The dataclass a field holds (itself, one arm of a union, or as the values of a mapping or items of a list)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Annotated:
        return _nested(args[0])
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return tp, ""
    if origin is dict and args:
        inner, key = _nested(args[1])
        return inner, "<name>." + key
    if origin is list and args:
        inner, key = _nested(args[0])
        return inner, "<i>." + key
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        arms = [_nested(a) for a in args if a is not type(None)]
        found = [arm for arm in arms if arm[0] is not None]
        if len(found) == 1:
            return found[0]
    return None, ""


def _show(value) -> str:
    from cellsim.config.typed_yaml import to_data

    data = to_data(value)
    if dataclasses.is_dataclass(value):
        return "(below)"
    if isinstance(data, dict) and len(str(data)) > 40:
        return "{...}"
    return "null" if data is None else str(data).replace("'", "")



def describe(name: str) -> dict:
    """One kind in full, as plain data (for ``--json`` and for the table)."""
    kind = registry.get(name)
    return {
        "kind": kind.name,
        "section": kind.section,
        "summary": kind.summary,
        "parameters": [dataclasses.asdict(p) for p in parameters(kind.config)],
        "channels": [{"signal": s, "type": t, "meaning": m} for s, t, m in kind.channels],
        "inputs": [{"input": s, "type": t, "meaning": m} for s, t, m in kind.inputs],
        "physical_sample_fields": list(kind.sample_fields),
        "command_fields": list(kind.command_fields),
        "files": list(kind.files),
    }


def catalogue() -> tuple[list[dict], list[str]]:
    """Every kind's name, section and summary; and one line per plug-in that failed to load."""
    kinds, errors = [], []
    for name in registry.kind_names():
        try:
            kind = registry.get(name)
        except registry.KindError as e:
            errors.append(str(e))
            continue
        kinds.append({"kind": kind.name, "section": kind.section, "summary": kind.summary})
    return kinds, errors


# --------------------------------------------------------------------------- docs/scenario-schema.md

SCHEMA_DOC = "docs/scenario-schema.md"
"""Where :func:`schema_markdown` is kept (``python -m cellsim.kinds_doc`` rewrites it; a test compares)."""


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ") or " "


def _table(params: list[Parameter]) -> list[str]:
    rows = ["| key | type | default | valid range | meaning |", "|---|---|---|---|---|"]
    for p in params:
        rows.append(
            f"| `{_cell(p.name)}` | {_cell(p.type)} | {_cell(p.default)} | {_cell(p.range)} | {_cell(p.doc)} |"
        )
    return rows


def schema_markdown() -> str:
    """Every key of a scenario file and of a risk model file, with its valid range, as Markdown.

    Generated from the dataclasses (types, defaults, ``Range`` annotations and the
    docstrings under the fields), so it cannot say other than what the loader checks.
    Only cellsim's own module kinds are listed (``cellsim modules`` shows plug-ins too).
    """
    from cellsim import scenario
    from cellsim.config.sampling import ChoiceSampler, SimplexSampler, UniformSampler
    from cellsim.config.typed_yaml import MAX_DEPTH, MAX_FILE_CHARS, MAX_NODES
    from cellsim.validation.coverage import MAX_SITUATIONS

    lines = [
        "# Scenario schema: every key, its default and its valid range",
        "",
        "<!-- Generated by `python -m cellsim.kinds_doc` from the schema's dataclasses; "
        "tests/test_bad_input.py checks it is current. Do not edit by hand. -->",
        "",
        "Units are SI (metres, seconds, radians; a `_deg` key is in degrees). A range is written",
        "`[lo, hi]` (ends included) or `(lo, hi)` (ends excluded); on a list such as a position it",
        "applies to each element. Ranges are checked when a file is loaded and on `--set`; a value",
        "out of range is one error line naming the file, line and key, and nothing runs. Besides:",
        "",
        "- every number is finite: `.nan`, `.inf` and `-.inf` are refused everywhere;",
        "- a module's `period` is a whole number of plant steps (`time_step`): every event of the cell falls on a plant step;",
        f"- a run (the scenario's `duration`, or `--duration`) takes at most {scenario.MAX_PLANT_STEPS:.0e} plant steps "
        f"(`duration / time_step`) and {scenario.MAX_MODULE_UPDATES:.0e} module updates (`duration / period`, summed over the modules);",
        f"- a coverage criterion has at most {MAX_SITUATIONS:,} situations (the product of its variables' values or bins);",
        "- a campaign sampler draws only values the keys it is drawn for accept;",
        f"- a YAML file is at most {MAX_FILE_CHARS:,} characters, nested at most {MAX_DEPTH} levels deep, and expands "
        f"(aliases counted each time they are used) to at most {MAX_NODES:,} values.",
        "",
        "## The scenario file",
        "",
        "`entities`, `behaviours` and `services` map module names to a module kind's keys: see",
        "[module kinds](#module-kinds). `campaign.samplers` map configuration points to a",
        "[sampler](#campaign-samplers).",
        "",
        *_table(parameters(scenario.Scenario)),
        "",
        "## Module kinds",
        "",
        "Each entry of `entities`, `behaviours` and `services` has `kind:` and that kind's keys.",
    ]
    for name in registry.kind_names():
        kind = registry.get(name)
        if not kind.config.__module__.startswith("cellsim."):
            continue  # a plug-in's kinds are documented by `cellsim modules`
        lines += ["", f"### `{kind.name}` ({kind.section})", "", kind.summary, "", *_table(parameters(kind.config))]
    lines += ["", "## Campaign samplers", ""]
    for sampler in (UniformSampler, ChoiceSampler, SimplexSampler):
        doc = " ".join((sampler.__doc__ or "").split("\n\n")[0].split())
        lines += [f"### `{_kind_literal(sampler)}`", "", doc, "", *_table(parameters(sampler)), ""]
    for name in registry.kind_names():
        kind = registry.get(name)
        if kind.config.__module__.startswith("cellsim."):
            for heading, sentence, schema in kind.formats:  # the files a kind reads (a risk model)
                lines += [f"## {heading}", "", sentence, "", *_table(parameters(schema)), ""]
    return "\n".join(lines)


def _kind_literal(cls: type) -> str:
    return typing.get_args(typing.get_type_hints(cls)["kind"])[0]


if __name__ == "__main__":
    import sys

    sys.stdout.write(schema_markdown())
