"""Strict YAML loading and schema-driven building of typed configuration.

This module is generic: it knows nothing about buses or controllers. A
configuration schema is a tree of frozen dataclasses whose fields are declared
with :func:`field_spec`; :func:`build` turns a parsed YAML mapping into an
instance of such a tree, checking every value on the way and rejecting
anything it does not know.

Every problem with a configuration file is reported as a :class:`ConfigError`
whose ``str()`` is one line naming the file and the dotted path of the
offending key, for example::

    config.yaml: bus.bitrate_bit_s: 2000000 is above the maximum 1000000

YAML dialect
------------
Files are parsed with a subclass of ``yaml.SafeLoader`` (no object is ever
constructed from a tag, nothing is executed) that in addition

* rejects duplicate keys, unknown or unsafe tags (``!!python/...``) and an
  empty document or a top level that is not a mapping;
* resolves plain scalars like the YAML 1.2 core schema, so that surprises of
  YAML 1.1 cannot silently change a value: only ``true``/``false`` are
  booleans (``yes``, ``no``, ``on``, ``off`` stay strings), ``010`` and
  ``1:30`` are strings (not the octal 8 and the sexagesimal 90), ``1e3`` and
  ``1.0e3`` are floats, and dates stay strings. Underscores in numbers
  (``1_000_000``) are accepted.

Schema conventions
------------------
* Every field is declared with :func:`field_spec` and has a ``doc``.
* A field without ``default`` is required in the YAML file. Safety-relevant
  parameters never get a default.
* Supported field types: ``int``, ``float``, ``bool``, ``str``,
  ``typing.Literal[...]``, ``tuple[X, ...]`` and fixed ``tuple[X, Y]`` of
  those scalars, nested config dataclasses, ``Optional[X]`` / ``X | None`` and
  ``dict[str, X]`` (named entries).
* A dataclass may define ``validate(self) -> None`` for cross-field checks; it
  reports a problem with :func:`fail`, naming the key relative to its own
  section, and :func:`build` prefixes the full dotted path.
"""

from __future__ import annotations

import collections.abc
import dataclasses
import difflib
import hashlib
import json
import math
import os
import re
import types
import typing
from pathlib import Path
from typing import Any, Literal, NoReturn, TypeVar, Union

import yaml

from config.errors import AiderError

__all__ = [
    "ConfigError",
    "FieldError",
    "FieldSpec",
    "build",
    "check_schema",
    "config_to_dict",
    "default_config_path",
    "fail",
    "field_spec",
    "load_as",
    "load_config",
    "load_yaml",
    "parse_as",
    "parse_config",
    "parse_override",
    "with_overrides",
]

T = TypeVar("T")

#: Key under which :func:`field_spec` stores its :class:`FieldSpec` in
#: ``dataclasses.Field.metadata``.
SPEC_METADATA_KEY = "aider_exo.config"
DERIVED_KEY = "aider_exo.derived"  # a field the root sets from another section (field_spec(derived=True))

_OVERRIDES_SOURCE = "<overrides>"
_MAX_SHOWN_CHARS = 40
_ENTRY_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]*")
_PLAIN_KEY = re.compile(r"[A-Za-z0-9_-]+")


# ---------------------------------------------------------------------------
# Errors
# ---------------------------------------------------------------------------


class ConfigError(AiderError):
    """A configuration file, text or override is invalid.

    ``str()`` is a single line ``SOURCE[:LINE[:COLUMN]]: [KEY: ]MESSAGE``.

    Parameters
    ----------
    message : str
        What is wrong, without location.
    key : str, optional
        Dotted path of the offending key (``bus.channel``,
        ``nodes.left_knee.gains[2]``).
    source : str, optional
        File name or a pseudo name such as ``<string>`` or ``<overrides>``.
    line, column : int, optional
        1-based position in the source, when known.
    """

    def __init__(
        self,
        message: str,
        *,
        key: str | None = None,
        source: str | None = None,
        line: int | None = None,
        column: int | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.key = key or None
        self.source = source
        self.line = line
        self.column = column

    def with_source(self, source: str) -> ConfigError:
        """Return a copy located in ``source`` (unchanged if already located)."""
        if self.source is not None:
            return self
        return ConfigError(
            self.message, key=self.key, source=source, line=self.line, column=self.column
        )

    def __str__(self) -> str:
        parts = []
        if self.source is not None:
            location = self.source
            if self.line is not None:
                location += f":{self.line}"
                if self.column is not None:
                    location += f":{self.column}"
            parts.append(location)
        if self.key:
            parts.append(self.key)
        parts.append(self.message)
        return " ".join(": ".join(parts).splitlines())


class FieldError(ConfigError):
    """A cross-field check of one section failed; raised by :func:`fail`.

    ``key`` is relative to the section whose ``validate()`` raised it;
    :func:`build` re-raises it as a :class:`ConfigError` with the full path.
    """

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message, key=key)
        self.args = (key, message)


def fail(key: str, message: str) -> NoReturn:
    """Report a failed check from a section's ``validate()`` method.

    Parameters
    ----------
    key : str
        Name of the offending field relative to the section (may be dotted
        for a nested field, or ``""`` for the section as a whole).
    message : str
        One-line description, e.g. ``"must not exceed max_n (3)"``.

    Raises
    ------
    FieldError
        Always.
    """
    raise FieldError(key, message)


# ---------------------------------------------------------------------------
# Field declaration
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FieldSpec:
    """Documentation and constraints of one configuration field.

    See :func:`field_spec` for the meaning of the attributes.
    """

    doc: str
    unit: str | None = None
    min: float | None = None
    max: float | None = None
    choices: tuple[Any, ...] | None = None
    allow_nonfinite: bool = False


def field_spec(
    *,
    doc: str,
    unit: str | None = None,
    min: float | None = None,  # noqa: A002 - reads naturally at the call site
    max: float | None = None,  # noqa: A002
    choices: collections.abc.Iterable[Any] | None = None,
    default: Any = dataclasses.MISSING,
    default_factory: Any = dataclasses.MISSING,
    allow_nonfinite: bool = False,
    derived: bool = False,
) -> Any:
    """Declare a configuration field of a frozen config dataclass.

    Parameters
    ----------
    doc : str
        What the field means (shown in documentation; required).
    unit : str, optional
        Physical unit, e.g. ``"bit/s"``; the field name carries it too.
    min, max : float, optional
        Inclusive bounds for numbers (for tuples: for every element).
    choices : iterable, optional
        Allowed values (prefer ``typing.Literal`` for strings).
    default : optional
        Value used when the key is absent. Without ``default`` or
        ``default_factory`` the key is required in the YAML file.
    default_factory : callable, optional
        Like ``dataclasses.field(default_factory=...)``, e.g. ``dict``.
    allow_nonfinite : bool
        Accept ``.nan`` and ``.inf`` for floats (rejected by default).
    derived : bool
        Not a key of this section: the root sets it from another section (the top-level
        ``hardware`` section in ``controller`` and ``sim``). Never read from nor written to a file,
        not compared; ``None`` until set.

    Returns
    -------
    dataclasses.Field
        To be assigned to the dataclass attribute.
    """
    if not isinstance(doc, str) or not doc.strip():
        raise TypeError("field_spec() needs a non-empty doc")
    if min is not None and max is not None and min > max:
        raise ValueError(f"field_spec(): min {min!r} exceeds max {max!r}")
    spec = FieldSpec(
        doc=doc,
        unit=unit,
        min=min,
        max=max,
        choices=tuple(choices) if choices is not None else None,
        allow_nonfinite=allow_nonfinite,
    )
    if derived:
        return dataclasses.field(default=None, compare=False, repr=False, metadata={SPEC_METADATA_KEY: spec, DERIVED_KEY: True})
    return dataclasses.field(
        default=default,
        default_factory=default_factory,
        metadata={SPEC_METADATA_KEY: spec},
    )


# ---------------------------------------------------------------------------
# Strict YAML loading
# ---------------------------------------------------------------------------

_TAG_PREFIX = "tag:yaml.org,2002:"
_NULL_TAG = _TAG_PREFIX + "null"
_MERGE_TAG = _TAG_PREFIX + "merge"
_ALLOWED_TAGS = frozenset(
    _TAG_PREFIX + name for name in ("null", "bool", "int", "float", "str", "seq", "map", "merge")
)


def _implicit_resolvers() -> dict[str | None, list[tuple[str, re.Pattern[str]]]]:
    """Resolver table of the strict loader (YAML 1.2 core schema, see module doc)."""
    table: dict[str | None, list[tuple[str, re.Pattern[str]]]] = {}

    def add(tag: str, pattern: str, first: str | list[str]) -> None:
        regexp = re.compile(pattern, re.X)
        for char in first:
            table.setdefault(char, []).append((_TAG_PREFIX + tag, regexp))

    add("bool", r"^(?:true|True|TRUE|false|False|FALSE)$", "tTfF")
    # Integers first: a float pattern must never claim "123".
    add(
        "int",
        r"""^(?:[-+]?0b[01][01_]*
              |[-+]?0x[0-9a-fA-F][0-9a-fA-F_]*
              |[-+]?(?:0|[1-9][0-9_]*))$""",
        "-+0123456789",
    )
    add(
        "float",
        r"""^(?:[-+]?[0-9][0-9_]*\.[0-9_]*(?:[eE][-+]?[0-9]+)?
              |[-+]?\.[0-9][0-9_]*(?:[eE][-+]?[0-9]+)?
              |[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+
              |[-+]?\.(?:inf|Inf|INF)
              |\.(?:nan|NaN|NAN))$""",
        "-+0123456789.",
    )
    add("null", r"^(?:~|null|Null|NULL|)$", ["~", "n", "N", ""])
    add("merge", r"^(?:<<)$", "<")
    return table


class _StrictLoader(yaml.SafeLoader):
    """``SafeLoader`` with the strict scalar resolution described in the module doc.

    Duplicate keys and tags are checked on the composed node graph by
    :func:`_check_nodes` before anything is constructed.
    """

    yaml_implicit_resolvers = _implicit_resolvers()

    def construct_object(self, node: yaml.Node, deep: bool = False) -> Any:
        # The safe constructors let a few Python errors escape for bad explicitly
        # tagged scalars (``!!int x``, ``!!float ''``); report them as YAML errors.
        try:
            return super().construct_object(node, deep=deep)
        except yaml.YAMLError:
            raise
        except (ArithmeticError, LookupError, TypeError, ValueError, AttributeError) as exc:
            raise yaml.constructor.ConstructorError(
                None, None, f"invalid {_short_tag(node.tag)} value: {exc}", node.start_mark
            ) from None


def _short_tag(tag: str) -> str:
    if tag.startswith(_TAG_PREFIX):
        return "!!" + tag[len(_TAG_PREFIX) :]
    return tag


def _yaml_error(exc: yaml.YAMLError, text: str, source: str) -> ConfigError:
    """One-line :class:`ConfigError` for a PyYAML error."""
    if isinstance(exc, yaml.MarkedYAMLError):
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context or "malformed document"
        message = f"invalid YAML: {problem}"
        if exc.problem and exc.context:
            message += f" ({exc.context}"
            if exc.context_mark is not None:
                message += (
                    f" at line {exc.context_mark.line + 1},"
                    f" column {exc.context_mark.column + 1}"
                )
            message += ")"
        if mark is None:
            return ConfigError(message, source=source)
        return ConfigError(message, source=source, line=mark.line + 1, column=mark.column + 1)
    if isinstance(exc, yaml.reader.ReaderError):
        char = exc.character
        code = ord(char) if isinstance(char, str) else char
        position = exc.position
        line = text.count("\n", 0, position) + 1
        column = position - (text.rfind("\n", 0, position) + 1) + 1
        return ConfigError(
            f"invalid YAML: unacceptable character U+{code:04X} ({exc.reason})",
            source=source,
            line=line,
            column=column,
        )
    return ConfigError(f"invalid YAML: {exc}", source=source)


def _key_segment(key: Any) -> str:
    """Render a mapping key as one segment of a dotted path."""
    if isinstance(key, str) and _PLAIN_KEY.fullmatch(key):
        return key
    return repr(key) if not isinstance(key, str) or len(key) <= _MAX_SHOWN_CHARS else (
        repr(key[:_MAX_SHOWN_CHARS]) + "..."
    )


def _join(path: str, segment: str) -> str:
    return f"{path}.{segment}" if path else segment


def _check_nodes(root: yaml.Node, loader: _StrictLoader, source: str) -> None:
    """Reject unsupported tags and duplicate keys anywhere in the node graph."""
    stack: list[tuple[yaml.Node, str]] = [(root, "")]
    visited: set[int] = set()
    while stack:
        node, path = stack.pop()
        if id(node) in visited:  # aliases share nodes; graphs may be cyclic
            continue
        visited.add(id(node))
        if node.tag not in _ALLOWED_TAGS:
            raise ConfigError(
                f"unsupported YAML tag {_short_tag(node.tag)!r}",
                source=source,
                line=node.start_mark.line + 1,
            )
        if isinstance(node, yaml.SequenceNode):
            stack.extend((item, f"{path}[{i}]") for i, item in enumerate(node.value))
        elif isinstance(node, yaml.MappingNode):
            first_line: dict[Any, int] = {}
            for key_node, value_node in node.value:
                if key_node.tag == _MERGE_TAG:
                    stack.append((value_node, path))
                    continue
                if not isinstance(key_node, yaml.ScalarNode):
                    stack.append((key_node, path))
                    stack.append((value_node, path))
                    continue
                if key_node.tag not in _ALLOWED_TAGS:
                    stack.append((key_node, path))  # reported when popped
                    continue
                key = loader.construct_object(key_node)
                key_path = _join(path, _key_segment(key))
                line = key_node.start_mark.line + 1
                if key in first_line:
                    raise ConfigError(
                        f"duplicate key (line {line}; first defined on line {first_line[key]})",
                        key=key_path,
                        source=source,
                    )
                first_line[key] = line
                stack.append((value_node, key_path))


_EMPTY = object()


def _parse_yaml_text(text: str, source: str) -> Any:
    """Parse one YAML document strictly; ``_EMPTY`` if it has no content."""
    try:
        loader = _StrictLoader(text)
    except yaml.YAMLError as exc:
        raise _yaml_error(exc, text, source) from None
    try:
        node = loader.get_single_node()
        if node is None:
            return _EMPTY
        _check_nodes(node, loader, source)
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        raise _yaml_error(exc, text, source) from None
    except RecursionError:
        raise ConfigError("invalid YAML: nesting is too deep", source=source) from None
    finally:
        loader.dispose()


def _read_text(path: Path, source: str) -> str:
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"cannot read file: {exc.strerror or exc}", source=source) from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"file is not valid UTF-8 text (byte offset {exc.start})", source=source
        ) from None


def load_yaml(source: str | os.PathLike[str], *, name: str | None = None) -> dict[Any, Any]:
    """Parse a configuration document into plain Python data.

    Parameters
    ----------
    source : str or os.PathLike
        A path object (``pathlib.Path``) is read as a UTF-8 file; a ``str``
        is the YAML text itself.
    name : str, optional
        Name used in error messages; defaults to the path, or ``"<string>"``
        for text.

    Returns
    -------
    dict
        The top-level mapping, with plain ``dict``/``list``/scalar values.

    Raises
    ------
    ConfigError
        Unreadable file, YAML syntax error (with line and column), duplicate
        key, unsupported tag, empty document, or a top level that is not a
        mapping.
    """
    if isinstance(source, os.PathLike):
        name = name if name is not None else os.fspath(source)
        text = _read_text(Path(source), name)
    elif isinstance(source, str):
        name = name if name is not None else "<string>"
        text = source
    else:
        raise TypeError(f"load_yaml() needs a str or a path, not {type(source).__name__}")
    data = _parse_yaml_text(text, name)
    if data is _EMPTY:
        raise ConfigError("document is empty; expected a mapping of sections", source=name)
    if not isinstance(data, dict):
        raise ConfigError(
            f"expected a mapping of sections at the top level, got {_describe(data)}",
            source=name,
        )
    return data


# ---------------------------------------------------------------------------
# Building typed objects
# ---------------------------------------------------------------------------


def _describe(value: Any) -> str:
    """Short one-line rendering of a YAML value for error messages."""
    if value is None:
        return "null (empty value)"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        if value.bit_length() > 128:
            return f"an integer with {len(format(value, 'x'))} hex digits"
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        if len(value) > _MAX_SHOWN_CHARS:
            return repr(value[:_MAX_SHOWN_CHARS]) + "..."
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "a list"
    if isinstance(value, collections.abc.Mapping):
        return "a mapping"
    return f"a value of type {type(value).__name__}"


def _fmt_bound(bound: float) -> str:
    if isinstance(bound, float) and bound.is_integer() and abs(bound) < 1e16:
        return repr(bound)
    return str(bound)


def _spec_of(field: dataclasses.Field[Any], cls: type) -> FieldSpec:
    spec = field.metadata.get(SPEC_METADATA_KEY)
    if not isinstance(spec, FieldSpec):
        raise TypeError(f"{cls.__qualname__}.{field.name} is not declared with field_spec()")
    return spec


def _config_fields(cls: type) -> list[tuple[dataclasses.Field[Any], Any, FieldSpec]]:
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"{cls!r} is not a dataclass type")
    if not cls.__dataclass_params__.frozen:  # type: ignore[attr-defined]
        raise TypeError(f"config dataclass {cls.__qualname__} must be frozen")
    hints = typing.get_type_hints(cls)
    return [
        (f, hints[f.name], _spec_of(f, cls)) for f in dataclasses.fields(cls) if f.init and not _is_derived(f)
    ]


def _is_derived(field: dataclasses.Field[Any]) -> bool:
    return bool(field.metadata.get(DERIVED_KEY))


def _is_required(field: dataclasses.Field[Any]) -> bool:
    return field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING


def _optional_arg(tp: Any) -> Any | None:
    """``X`` for ``Optional[X]`` / ``X | None``; ``None`` for other types."""
    if typing.get_origin(tp) in (Union, types.UnionType):
        args = typing.get_args(tp)
        others = [a for a in args if a is not type(None)]
        if len(args) == 2 and len(others) == 1:
            return others[0]
        raise TypeError(f"unsupported union type {tp!r}; only Optional[X] is supported")
    return None


def _check_choices(value: Any, choices: tuple[Any, ...] | None, key: str) -> None:
    if choices is None:
        return
    if any(type(value) is type(c) and value == c for c in choices):
        return
    if len(choices) == 1:
        raise ConfigError(f"expected {choices[0]}, got {_describe(value)}", key=key)
    listed = ", ".join(str(c) for c in choices)
    raise ConfigError(f"{_describe(value)} is not one of: {listed}", key=key)


def _check_range(value: Any, number: float, spec: FieldSpec, key: str) -> None:
    if spec.min is not None and number < spec.min:
        raise ConfigError(
            f"{_describe(value)} is below the minimum {_fmt_bound(spec.min)}", key=key
        )
    if spec.max is not None and number > spec.max:
        raise ConfigError(
            f"{_describe(value)} is above the maximum {_fmt_bound(spec.max)}", key=key
        )


def _convert(tp: Any, value: Any, key: str, spec: FieldSpec) -> Any:
    """Check ``value`` (plain YAML data) against type ``tp``; return the typed value."""
    inner = _optional_arg(tp)
    if inner is not None:
        return None if value is None else _convert(inner, value, key, spec)
    origin = typing.get_origin(tp)

    if origin is Literal:
        _check_choices(value, typing.get_args(tp), key)
        return value

    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if not isinstance(value, collections.abc.Mapping):
            raise ConfigError(f"expected a mapping (section), got {_describe(value)}", key=key)
        return build(tp, value, key)

    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(
                f"expected a boolean (true or false), got {_describe(value)}", key=key
            )
        _check_choices(value, spec.choices, key)
        return value

    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"expected an integer, got {_describe(value)}", key=key)
        _check_range(value, value, spec, key)
        _check_choices(value, spec.choices, key)
        return value

    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"expected a number, got {_describe(value)}", key=key)
        try:
            number = float(value)
        except OverflowError:
            raise ConfigError(f"{_describe(value)} is too large for a float", key=key) from None
        if not math.isfinite(number) and not spec.allow_nonfinite:
            raise ConfigError(f"expected a finite number, got {_describe(value)}", key=key)
        if not math.isnan(number):
            _check_range(value, number, spec, key)
        _check_choices(number, spec.choices, key)
        return number

    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(
                f"expected a string, got {_describe(value)} (quote it to make it a string)",
                key=key,
            )
        _check_choices(value, spec.choices, key)
        return value

    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"expected a list, got {_describe(value)}", key=key)
        if len(args) == 2 and args[1] is Ellipsis:
            item_types = [args[0]] * len(value)
        else:
            if len(value) != len(args):
                raise ConfigError(
                    f"expected a list of {len(args)} items, got {len(value)}", key=key
                )
            item_types = list(args)
        return tuple(
            _convert(item_tp, item, f"{key}[{i}]", spec)
            for i, (item_tp, item) in enumerate(zip(item_types, value))
        )

    if origin in (dict, collections.abc.Mapping):
        key_tp, value_tp = typing.get_args(tp)
        if key_tp is not str:
            raise TypeError(f"unsupported mapping key type {key_tp!r}; use dict[str, X]")
        if not isinstance(value, collections.abc.Mapping):
            raise ConfigError(
                f"expected a mapping of named entries, got {_describe(value)}", key=key
            )
        result = {}
        for name, item in value.items():
            if not isinstance(name, str) or not _ENTRY_NAME.fullmatch(name):
                raise ConfigError(
                    f"entry name {_describe(name)} must consist of letters, digits,"
                    " '_' and '-' and not start with '-'",
                    key=key,
                )
            result[name] = _convert(value_tp, item, _join(key, name), spec)
        return result

    raise TypeError(f"unsupported configuration field type {tp!r} (at {key or 'top level'})")


def build(cls: type[T], data: Any, path: str = "") -> T:
    """Build config dataclass ``cls`` from plain YAML data, checking everything.

    Keys are checked in field declaration order, then unknown keys are
    reported (an unknown key is reported instead of a missing required key,
    since it is most likely a misspelling). Finally the optional
    ``validate()`` method of the new object runs.

    Parameters
    ----------
    cls : type
        A frozen dataclass whose fields are declared with :func:`field_spec`.
    data : Mapping
        Parsed YAML for this section.
    path : str
        Dotted path of this section, used as prefix in errors (``""`` for
        the top level).

    Returns
    -------
    cls
        The built object.

    Raises
    ------
    ConfigError
        With ``key`` set to the full dotted path of the offending key and no
        ``source`` (callers add it with :meth:`ConfigError.with_source`).
    TypeError
        If ``cls`` is not a valid config schema (a programming error).
    """
    fields = _config_fields(cls)
    if not isinstance(data, collections.abc.Mapping):
        raise ConfigError(f"expected a mapping, got {_describe(data)}", key=path or None)
    names = [f.name for f, _, _ in fields]
    unknown = [k for k in data if k not in names]

    def unknown_key_error() -> ConfigError:
        bad = unknown[0]
        moved = getattr(cls, "MOVED_KEYS", {}).get(_key_segment(bad))
        if moved is not None:  # a key of an earlier file format, now elsewhere
            return ConfigError(f"this key is now {moved}", key=_join(path, _key_segment(bad)))
        message = f"unknown key; expected one of: {', '.join(sorted(names))}"
        close = difflib.get_close_matches(_key_segment(bad), names, n=1)
        if close:
            message += f" (did you mean {close[0]!r}?)"
        return ConfigError(message, key=_join(path, _key_segment(bad)))

    kwargs = {}
    for field, tp, spec in fields:
        key = _join(path, field.name)
        if field.name in data:
            kwargs[field.name] = _convert(tp, data[field.name], key, spec)
        elif _is_required(field):
            if unknown:
                raise unknown_key_error()
            raise ConfigError("missing required key", key=key)
    if unknown:
        raise unknown_key_error()

    obj = cls(**kwargs)
    validate = getattr(obj, "validate", None)
    if validate is not None:
        try:
            validate()
        except FieldError as exc:
            full_key = _join(path, exc.key) if exc.key else path
            raise ConfigError(exc.message, key=full_key or None) from None
    return obj


def check_schema(cls: type) -> None:
    """Check that ``cls`` is a well-formed config schema, recursively.

    Every class must be a frozen dataclass, every field declared with
    :func:`field_spec` and of a supported type, and every default must pass
    the field's own checks.

    Raises
    ------
    TypeError
        Describing the first problem found.
    """
    seen: set[type] = set()

    def check_type(tp: Any, where: str) -> None:
        inner = _optional_arg(tp)
        if inner is not None:
            check_type(inner, where)
            return
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if tp in (int, float, bool, str):
            return
        if origin is Literal:
            if not args or not all(isinstance(a, (str, int)) for a in args):
                raise TypeError(f"{where}: Literal choices must be strings or integers")
            return
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            check_class(tp)
            return
        if origin is tuple:
            items = args[:1] if len(args) == 2 and args[1] is Ellipsis else args
            if not items:
                raise TypeError(f"{where}: empty tuple type")
            for item in items:
                if item not in (int, float, bool, str) and typing.get_origin(item) is not Literal:
                    raise TypeError(f"{where}: tuple items must be scalars, not {item!r}")
            return
        if origin in (dict, collections.abc.Mapping):
            if args[0] is not str:
                raise TypeError(f"{where}: mapping keys must be str")
            check_type(args[1], where)
            return
        raise TypeError(f"{where}: unsupported configuration field type {tp!r}")

    def check_class(klass: type) -> None:
        if klass in seen:
            return
        seen.add(klass)
        for field, tp, spec in _config_fields(klass):
            where = f"{klass.__qualname__}.{field.name}"
            check_type(tp, where)
            if field.default is not dataclasses.MISSING:
                default = field.default
            elif field.default_factory is not dataclasses.MISSING:
                default = field.default_factory()
            else:
                continue
            try:
                _convert(tp, _to_plain(default), field.name, spec)
            except ConfigError as exc:
                raise TypeError(f"{where}: invalid default: {exc}") from None

    check_class(cls)


def _to_plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {
            f.name: _to_plain(getattr(value, f.name)) for f in dataclasses.fields(value) if f.init and not _is_derived(f)
        }
    if isinstance(value, (list, tuple)):
        return [_to_plain(v) for v in value]
    if isinstance(value, collections.abc.Mapping):
        return {k: _to_plain(v) for k, v in value.items()}
    return value


def config_to_dict(config: Any) -> dict[str, Any]:
    """Plain ``dict``/``list``/scalar form of a config object.

    The result can be dumped with ``yaml.safe_dump`` or ``json.dumps``, and
    ``build(type(config), config_to_dict(config)) == config``.
    """
    if not (dataclasses.is_dataclass(config) and not isinstance(config, type)):
        raise TypeError(f"expected a config dataclass instance, got {type(config).__name__}")
    return _to_plain(config)


def config_hash(config: Any) -> str:
    """SHA-256 of a config object's canonical JSON form (equal configurations, equal hashes)."""
    text = json.dumps(config_to_dict(config), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


# ---------------------------------------------------------------------------
# Entry points
# ---------------------------------------------------------------------------


def parse_as(cls: type[T], text: str, source: str = "<string>") -> T:
    """Parse YAML ``text`` and build ``cls`` from it; errors name ``source``."""
    data = load_yaml(text, name=source)
    try:
        return build(cls, data)
    except ConfigError as exc:
        raise exc.with_source(source) from None


def load_as(cls: type[T], path: str | os.PathLike[str]) -> T:
    """Read the YAML file ``path`` and build ``cls`` from it."""
    source = os.fspath(path)
    data = load_yaml(Path(path), name=source)
    try:
        return build(cls, data)
    except ConfigError as exc:
        raise exc.with_source(source) from None


def _schema_root() -> type:
    # Imported here, not at module level: ``schema`` imports this module.
    from .schema import Config

    return Config


def load_config(path: str | os.PathLike[str]) -> Any:
    """Load the aider-exo configuration file ``path``.

    Returns
    -------
    config.schema.Config

    Raises
    ------
    ConfigError
        One line naming the file and the offending key.
    """
    return load_as(_schema_root(), path)


def parse_config(text: str, source: str = "<string>") -> Any:
    """Parse aider-exo configuration YAML ``text``; errors name ``source``.

    Returns
    -------
    config.schema.Config
    """
    return parse_as(_schema_root(), text, source)


def default_config_path() -> Path:
    """Path of the ``default.yaml`` shipped inside this package."""
    return Path(__file__).resolve().with_name("default.yaml")


def with_overrides(
    config: T, overrides: collections.abc.Mapping[str, Any], *, source: str = _OVERRIDES_SOURCE
) -> T:
    """Return a copy of ``config`` with dotted-path overrides applied.

    The result is rebuilt through :func:`build`, so every check (ranges,
    choices, cross-field ``validate()``) applies to it as to a file.

    Parameters
    ----------
    config : config dataclass instance
        Typically the result of :func:`load_config`.
    overrides : Mapping[str, Any]
        ``{"bus.interface": "socketcan", "bus.channel": "vcan0"}``. Values
        are plain data (lists for tuples, dicts for sections); see
        :func:`parse_override` for ``KEY=VALUE`` strings from a command line.
    source : str
        Name used in error messages.

    Raises
    ------
    ConfigError
        Naming ``source`` and the dotted key.
    """
    data = config_to_dict(config)
    for dotted, value in overrides.items():
        parts = dotted.split(".") if isinstance(dotted, str) else []
        if not parts or not all(parts):
            raise ConfigError(
                f"invalid override key {dotted!r}; expected a dotted path such as 'bus.channel'",
                source=source,
            )
        node = data
        for i, part in enumerate(parts[:-1]):
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            elif not isinstance(child, dict):
                raise ConfigError(
                    f"cannot be set: {'.'.join(parts[: i + 1])} is a value, not a section",
                    key=dotted,
                    source=source,
                )
            node = child
        node[parts[-1]] = _to_plain(value)
    try:
        return build(type(config), data)
    except ConfigError as exc:
        raise exc.with_source(source) from None


def parse_override(text: str) -> tuple[str, Any]:
    """Split a command-line override ``KEY=VALUE``; the value is parsed as YAML.

    ``"bus.bitrate_bit_s=500000"`` gives ``("bus.bitrate_bit_s", 500000)``,
    ``"bus.channel=vcan0"`` gives ``("bus.channel", "vcan0")``. The value uses
    the same strict YAML dialect as files (``[1.0, 2.0]`` is a list).

    Raises
    ------
    ConfigError
        If there is no ``=`` or the value is not valid YAML.
    """
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(
            f"invalid override {_describe(text)}; expected KEY=VALUE such as bus.channel=vcan0",
            source=_OVERRIDES_SOURCE,
        )
    try:
        value = _parse_yaml_text(raw, _OVERRIDES_SOURCE)
    except ConfigError as exc:
        raise ConfigError(exc.message, key=key, source=_OVERRIDES_SOURCE) from None
    return key, (None if value is _EMPTY else value)
