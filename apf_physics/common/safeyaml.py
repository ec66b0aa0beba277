"""YAML files read within limits, and users' values shown in messages.

:func:`read_yaml_file` reads world files, curricula and other YAML configuration: a regular
file of at most :data:`~apf_physics.common.safefile.MAX_FILE_BYTES`, one document, built from the
parser's events with its nesting (:data:`MAX_DEPTH`), the length of each value
(:data:`MAX_SCALAR_CHARS`) and the count of values, aliases expanded (:data:`MAX_NODES`),
checked before any Python object is built. A broken or hostile file gets one clear refusal
naming it, never a traceback, a hang or a raw memory error.

:func:`shortened` and :func:`key_text` show what a file holds in a message: one line, a few
elements, a huge integer by its digit count.
"""

from __future__ import annotations

import math
import re
import reprlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from apf_physics.errors import UserError
from apf_physics.common.safefile import read_regular_file

# -- limits (docs/world-files.md): what any YAML file (world or curriculum) may hold ---------
MAX_DEPTH = 32
"""Deepest nesting of lists and mappings (a world file needs 5)."""
MAX_NODES = 500_000
"""Most values in one file (numbers, strings, lists, mappings), every alias counted as what it expands to."""
MAX_SCALAR_CHARS = 4096
"""Longest single value [characters]: a path fits; an integer stays below Python's 4,300-digit parsing limit."""


# -- values in messages ----------------------------------------------------------------------
class _ShortRepr(reprlib.Repr):
    """``repr`` cut to a few elements and levels; huge integers by their digit count (their
    ``repr`` would raise beyond 4,300 digits)."""

    def __init__(self):
        super().__init__()
        self.maxlevel, self.maxlist, self.maxtuple, self.maxdict, self.maxset = 3, 4, 4, 4, 4
        self.maxstring, self.maxlong, self.maxother = 40, 24, 40

    def repr_int(self, x: int, level: int) -> str:
        if x.bit_length() > 256:
            return f"<an integer of about {int(x.bit_length() * math.log10(2)) + 1} digits>"
        return super().repr_int(x, level)


_REPR = _ShortRepr()


def shortened(value: Any, limit: int = 60) -> str:
    """``value`` for a message: one line of at most ``limit`` characters, whatever it is."""
    try:
        text = _REPR.repr(value)
    except Exception:  # a value whose repr fails: say what it is
        text = f"<{type(value).__name__}>"
    text = text.replace("\n", " ")
    return text if len(text) <= limit else text[:limit - 3] + "..."


def key_text(key: Any) -> str:
    """A mapping key as messages show it: plain if it is a short printable string."""
    if isinstance(key, str) and key.isprintable() and 0 < len(key) <= 40:
        return key
    return shortened(key, 40)


# -- reading ---------------------------------------------------------------------------------
_PARSER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)   # libyaml's parser when PyYAML has it


class _Resolver(yaml.resolver.Resolver):
    """YAML 1.1's implicit types, plus the floats of YAML 1.2 and JSON (``1e-9``, ``2.5E3``), which
    YAML 1.1 would read as strings."""


_Resolver.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789"))
_RESOLVER = _Resolver()
_CONSTRUCTOR = yaml.constructor.SafeConstructor()
_SEQUENCE_TAGS = (None, "!", "tag:yaml.org,2002:seq")
_SCALAR_TAGS = {f"tag:yaml.org,2002:{name}" for name in ("null", "bool", "int", "float", "str", "binary", "timestamp")}
_MERGE = object()  # the key ``<<``: merge the mappings that are its value
_MAPPING_TAGS = (None, "!", "tag:yaml.org,2002:map")


class _YamlLimit(Exception):
    """The text breaks a limit; the message says where and which."""


@dataclass
class _Open:
    """A list or mapping the parser has opened and not yet closed."""

    value: list | dict
    anchor: str | None
    size: int = 1                      # values in it so far, itself included, aliases expanded
    key: Any = None                    # in a mapping: the key waiting for its value
    has_key: bool = False
    merges: list | None = None         # mappings merged in with ``<<``


def _scalar(event: yaml.ScalarEvent) -> Any:
    """The Python value of a scalar, by the safe loader's rules for its tag."""
    tag = event.tag if event.tag not in (None, "!") else _RESOLVER.resolve(yaml.ScalarNode, event.value, event.implicit)
    if tag == "tag:yaml.org,2002:merge":
        return _MERGE
    construct = _CONSTRUCTOR.yaml_constructors.get(tag) if tag in _SCALAR_TAGS else None
    if construct is None:
        raise _YamlLimit(f"line {event.start_mark.line + 1}: unsupported tag {shortened(tag)}")
    return construct(_CONSTRUCTOR, yaml.ScalarNode(tag, event.value, event.start_mark, event.end_mark, event.style))


def _load_yaml(text: str) -> Any:
    """The document in ``text``, built from the parser's events with the limits checked as they come.

    What ``yaml.safe_load`` returns (one document; anchors and aliases share one object;
    ``<<`` merges), but nothing is built beyond the limits: nesting deeper than
    :data:`MAX_DEPTH`, a value longer than :data:`MAX_SCALAR_CHARS`, more than
    :data:`MAX_NODES` values with every alias counted as what it expands to (an alias bomb is
    refused after the few events that define it), an alias inside what it names, and a key
    repeated in one mapping (YAML would keep only the last: what was written first would be lost).

    Raises:
        _YamlLimit: a limit is broken or a value cannot be built.
        yaml.YAMLError: ``text`` is not YAML.
    """
    nodes, documents = 0, 0
    stack: list[_Open] = []
    anchors: dict[str, tuple[Any, int]] = {}   # anchor -> (value, values it expands to)
    unfinished: set[str] = set()              # anchors of collections still open
    document: Any = None
    for event in yaml.parse(text, Loader=_PARSER):
        where = f"line {event.start_mark.line + 1}"
        if isinstance(event, yaml.DocumentStartEvent):
            documents += 1
            if documents > 1:
                raise _YamlLimit(f"{where}: a second document; the file must hold one")
            continue
        if isinstance(event, yaml.CollectionStartEvent):
            if len(stack) >= MAX_DEPTH:
                raise _YamlLimit(f"{where}: nested deeper than {MAX_DEPTH} levels")
            mapping = isinstance(event, yaml.MappingStartEvent)
            if event.tag not in (_MAPPING_TAGS if mapping else _SEQUENCE_TAGS):
                raise _YamlLimit(f"{where}: unsupported tag {shortened(event.tag)}")
            stack.append(_Open({} if mapping else [], event.anchor))
            if event.anchor:
                unfinished.add(event.anchor)
            continue
        if isinstance(event, yaml.CollectionEndEvent):
            frame = stack.pop()
            value, size, count = frame.value, frame.size, 1   # its contents are counted already
            if frame.merges:  # explicit keys win, then the first merged mapping, then the next
                merged: dict = {}
                for source in reversed(frame.merges):
                    merged.update(source)
                merged.update(value)
                value.clear()
                value.update(merged)
            if frame.anchor:
                anchors[frame.anchor] = (value, size)
                unfinished.discard(frame.anchor)
        elif isinstance(event, yaml.ScalarEvent):
            if len(event.value) > MAX_SCALAR_CHARS:
                raise _YamlLimit(f"{where}: a value of {len(event.value):,} characters (at most {MAX_SCALAR_CHARS:,})")
            value = _scalar(event)
            size = count = 1
            if event.anchor:
                anchors[event.anchor] = (value, 1)
        elif isinstance(event, yaml.AliasEvent):
            name = key_text(event.anchor)
            if event.anchor in unfinished:
                raise _YamlLimit(f"{where}: alias *{name} is inside the collection it names")
            if event.anchor not in anchors:
                raise _YamlLimit(f"{where}: alias *{name} has no anchor &{name} before it")
            value, size = anchors[event.anchor]
            count = size
        else:  # stream and document ends
            continue
        nodes += count
        if nodes > MAX_NODES:
            raise _YamlLimit(f"{where}: more than {MAX_NODES:,} values (aliases counted as what they expand to)")
        if value is _MERGE and not (stack and isinstance(stack[-1].value, dict) and not stack[-1].has_key):
            raise _YamlLimit(f"{where}: '<<' is only a mapping's key")
        if not stack:
            document = value
            continue
        parent = stack[-1]
        parent.size += size
        if isinstance(parent.value, list):
            parent.value.append(value)
        elif not parent.has_key:
            if value is _MERGE:
                if parent.merges is not None:
                    raise _YamlLimit(f"{where}: key '<<' appears twice in one mapping")
                parent.merges = []
            else:
                try:
                    hash(value)
                except TypeError:
                    raise _YamlLimit(f"{where}: a {type(value).__name__} as a mapping key") from None
                if value in parent.value:
                    raise _YamlLimit(f"{where}: key {shortened(value)} appears twice in one mapping")
            parent.key, parent.has_key = value, True
        else:
            if parent.key is _MERGE:
                sources = [value] if isinstance(value, dict) else value
                if not isinstance(sources, list) or not all(isinstance(m, dict) for m in sources):
                    raise _YamlLimit(f"{where}: '<<' merges a mapping or a list of mappings")
                parent.merges.extend(sources)
            else:
                parent.value[parent.key] = value
            parent.has_key = False
    return document


def read_yaml_file(path: str | Path, kind: str, error: type[UserError] = UserError) -> Any:
    """Read a YAML file within the limits, turning every failure into one ``error`` naming the file.

    Args:
        path: The file: a regular file of at most :data:`MAX_FILE_BYTES`.
        kind: What the file is, for messages (``"world"``, ``"curriculum"``).
        error: The exception class to raise.
    """
    source = str(path)
    data = read_regular_file(path, kind, error)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{source}: cannot read the {kind} file (not UTF-8 text: byte {exc.start:,} "
                    f"is {data[exc.start]:#04x})") from None
    try:
        return _load_yaml(text)
    except _YamlLimit as exc:
        raise error(f"{source}: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise error(f"{source}: not valid YAML{where}: {shortened(getattr(exc, 'problem', None) or exc, 200)}") from None
    except (ValueError, OverflowError, TypeError) as exc:  # a value YAML's constructors reject (a date like 2024-13-45)
        raise error(f"{source}: not valid YAML: {shortened(str(exc), 200)}") from None
