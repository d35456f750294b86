"""A safe YAML reader with YAML 1.2 core-schema scalars and bounds against hostile documents.

PyYAML implements YAML 1.1, whose implicit typing reads ``1:30`` as 90 (sexagesimal), ``010`` as 8
(octal) and ``1_5`` as 15, and ``yes``/``on`` as booleans. Task files are YAML 1.2, core schema:

========  ==============================================================================
null      ``~``, ``null``, ``Null``, ``NULL``, empty
bool      ``true``, ``True``, ``TRUE``, ``false``, ``False``, ``FALSE``
int       ``[-+]?[0-9]+`` decimal, ``0o[0-7]+`` octal, ``0x[0-9a-fA-F]+`` hex
float     ``[-+]?(.[0-9]+ | [0-9]+(.[0-9]*)?)([eE][-+]?[0-9]+)?``, ``[-+]?.inf``, ``.nan``
str       everything else: ``1:30``, ``1_5``, ``yes``, ``0b101``, ``2024-01-01``
========  ==============================================================================

One deliberate exception: a decimal integer with a leading zero (``010``, ``-007``) is read as a
string, not as 10, because a YAML 1.1 reader (and most people) would take it for octal; a numeric
key then refuses it with a message naming the key. Merge keys (``<<: *anchor``, a YAML 1.1 type)
are accepted: keys written in the mapping win over merged ones, and earlier mappings in a merged
list win over later ones. Duplicate keys are an error.

Bounds, checked on the node graph before any Python object is built, so that an answer comes in
well under a second: nesting deeper than ``MAX_DEPTH`` collections, or a document whose aliases
expand it to more than ``MAX_VALUES`` values (an "alias bomb"), or an alias that refers to its own
ancestor, is a ``yaml.YAMLError`` with a position.
"""
from __future__ import annotations

import math
import re
from typing import Any, ClassVar

import yaml
from yaml.composer import ComposerError
from yaml.constructor import ConstructorError
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode
from yaml.scanner import ScannerError

MAX_DEPTH = 100  # nested collections; a task needs about 5
MAX_VALUES = 100_000  # scalars and collections after alias expansion; a 150-joint task needs a few thousand
MAX_DIGITS = 1000  # an integer literal longer than this is refused (Python refuses to convert > 4300 digits)

TAG = "tag:yaml.org,2002:"
NULL = re.compile(r"^(?:~|null|Null|NULL|)$")
BOOL = re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$")
INT = re.compile(r"^(?:[-+]?(?:0|[1-9][0-9]*)|0o[0-7]+|0x[0-9a-fA-F]+)$")  # no leading zeros (see above)
INT_EXPLICIT = re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$")  # for `!!int 010` (YAML 1.2: 10)
FLOAT = re.compile(
    r"^(?:[-+]?(?:\.[0-9]+|[0-9]+\.[0-9]*|[0-9]+(?:\.[0-9]*)?[eE][-+]?[0-9]+|\.[0-9]+[eE][-+]?[0-9]+)"
    r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
)
FLOAT_EXPLICIT = re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
                            r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")
MERGE = re.compile(r"^<<$")

# Plain scalars that a YAML 1.1 reader takes for numbers but YAML 1.2 reads as text (for error hints).
YAML11_NUMBER = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?::[0-5]?[0-9])+(?:\.[0-9_]*)?|0[0-9_]+|[0-9][0-9_]*_[0-9_]*"
                           r"(?:\.[0-9_]*)?|0b[01_]+|0x[0-9a-fA-F_]+|0o[0-7_]+)$")


class Yaml12Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 core-schema implicit types, merge keys, no duplicate keys, and bounds."""

    yaml_implicit_resolvers: ClassVar[dict] = {}  # replaces YAML 1.1's (filled below)
    yaml_constructors: ClassVar[dict] = {}

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._depth = 0

    # ---------------------------------------------------------------- scanning (speed)
    # PyYAML checks every saved "possible simple key" (one per open flow collection) each time it
    # needs a token, and looks up to 1024 characters ahead: ``[[[[…`` costs ~10^6 Python steps (a
    # second) before the depth bound below is reached. The keys are saved in the order of their
    # position (a key at a flow level is removed when that level closes, so later keys sit at deeper
    # levels), which makes the stale ones a prefix of the dict and the first one the nearest: the two
    # checks below stop at the first live key instead of visiting all. Same results (tested against
    # PyYAML's own methods), in C-speed dict iteration.
    def stale_possible_simple_keys(self) -> None:
        """Remove saved simple keys that can no longer be keys (another line, or > 1024 characters back)."""
        keys = self.possible_simple_keys
        while keys:
            level, key = next(iter(keys.items()))
            if key.line == self.line and self.index - key.index <= 1024:
                return
            if key.required:
                raise ScannerError("while scanning a simple key", key.mark, "could not find expected ':'",
                                   self.get_mark())
            del keys[level]

    def next_possible_simple_key(self) -> int | None:
        """The token number of the nearest saved simple key (the first saved), or None."""
        keys = self.possible_simple_keys
        return next(iter(keys.values())).token_number if keys else None

    # ---------------------------------------------------------------- composing (bounds)
    def compose_node(self, parent: Node | None, index: Any) -> Node:
        """Compose one node, refusing collections nested deeper than ``MAX_DEPTH``."""
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                raise ComposerError(None, None, f"collections nested deeper than {MAX_DEPTH} levels",
                                    self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def compose_document(self) -> Node:
        """Compose the document and check its alias-expanded size before anything is constructed."""
        node = super().compose_document()
        _check_expanded_size(node)
        return node


def _children(node: Node) -> list[Node]:
    if isinstance(node, SequenceNode):
        return list(node.value)
    if isinstance(node, MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def _check_expanded_size(root: Node) -> None:
    """Raise ComposerError when aliases expand ``root`` past ``MAX_VALUES`` values or form a cycle.

    Linear in the number of distinct nodes: each node's expanded size is computed once (iteratively,
    so the check itself cannot overflow the stack) and capped at ``MAX_VALUES + 1``.
    """
    size: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            on_path.discard(key)
            total = 1 + sum(size[id(child)] for child in _children(node))
            size[key] = min(total, MAX_VALUES + 1)
            if size[key] > MAX_VALUES:
                raise ComposerError(None, None, f"the document expands to more than {MAX_VALUES} values "
                                    "(through aliases?); a task needs far fewer", node.start_mark)
            continue
        if key in size:
            continue
        if key in on_path:
            raise ComposerError(None, None, "an alias refers to a collection that contains it (a cycle)",
                                node.start_mark)
        on_path.add(key)
        stack.append((node, True))
        stack.extend((child, False) for child in _children(node) if id(child) not in size)


# -------------------------------------------------------------------- constructing (core schema)
def _scalar(loader: Yaml12Loader, node: Node) -> str:
    if not isinstance(node, ScalarNode):
        raise ConstructorError(None, None, f"expected a scalar for tag {node.tag}, found a {node.id}", node.start_mark)
    return loader.construct_scalar(node)


def _null(loader: Yaml12Loader, node: Node) -> None:
    value = _scalar(loader, node)
    if not NULL.match(value):
        raise ConstructorError(None, None, f"{value[:40]!r} is not a YAML 1.2 null", node.start_mark)


def _bool(loader: Yaml12Loader, node: Node) -> bool:
    value = _scalar(loader, node)
    if not BOOL.match(value):
        raise ConstructorError(None, None, f"{value[:40]!r} is not a YAML 1.2 boolean (true or false)",
                               node.start_mark)
    return value.lower() == "true"


def _int(loader: Yaml12Loader, node: Node) -> int:
    value = _scalar(loader, node)
    if not INT_EXPLICIT.match(value):
        raise ConstructorError(None, None, f"{value[:40]!r} is not a YAML 1.2 integer", node.start_mark)
    if len(value) > MAX_DIGITS:
        raise ConstructorError(None, None, f"an integer with more than {MAX_DIGITS} digits", node.start_mark)
    return int(value, 0 if value.startswith(("0o", "0x")) else 10)


def _float(loader: Yaml12Loader, node: Node) -> float:
    value = _scalar(loader, node)
    if not FLOAT_EXPLICIT.match(value):
        raise ConstructorError(None, None, f"{value[:40]!r} is not a YAML 1.2 float", node.start_mark)
    lowered = value.lower()
    if lowered.endswith(".inf"):
        return -math.inf if value.startswith("-") else math.inf
    if lowered == ".nan":
        return math.nan
    return float(value)


def _str(loader: Yaml12Loader, node: Node) -> str:
    return _scalar(loader, node)


def _seq(loader: Yaml12Loader, node: Node) -> list:
    if not isinstance(node, SequenceNode):
        raise ConstructorError(None, None, f"expected a sequence, found a {node.id}", node.start_mark)
    return [loader.construct_object(child, deep=True) for child in node.value]


def _hashable_key(loader: Yaml12Loader, key_node: Node) -> Any:
    key = loader.construct_object(key_node, deep=True)
    try:
        hash(key)
    except TypeError:
        raise ConstructorError(None, None, "a mapping key must be a scalar, not a collection",
                               key_node.start_mark) from None
    return key


def _merged(loader: Yaml12Loader, value_node: Node) -> dict:
    """The mappings named by a merge key ``<<``: earlier mappings in a list win over later ones."""
    nodes = value_node.value if isinstance(value_node, SequenceNode) else [value_node]
    out: dict = {}
    for sub in nodes:
        if not isinstance(sub, MappingNode):
            raise ConstructorError(None, None, "a merge key << expects a mapping or a list of mappings "
                                   f"(e.g. <<: *defaults), found a {sub.id}", sub.start_mark)
        for key, value in loader.construct_object(sub, deep=True).items():
            out.setdefault(key, value)
    return out


def _map(loader: Yaml12Loader, node: Node) -> dict:
    """A mapping with merge keys resolved; a repeated key (``<<`` included) is an error."""
    if not isinstance(node, MappingNode):
        raise ConstructorError(None, None, f"expected a mapping, found a {node.id}", node.start_mark)
    own: dict = {}
    merged: dict | None = None
    for key_node, value_node in node.value:
        if key_node.tag == TAG + "merge":
            if merged is not None:
                raise ConstructorError(None, None, "duplicate merge key <<", key_node.start_mark)
            merged = _merged(loader, value_node)
            continue
        key = _hashable_key(loader, key_node)
        if key in own:
            raise ConstructorError(None, None, f"duplicate key {_short(key)} (a later value would silently "
                                   "replace the earlier)", key_node.start_mark)
        own[key] = loader.construct_object(value_node, deep=True)
    if merged is None:
        return own
    return {**merged, **own}


def _short(key: Any) -> str:
    text = repr(key) if not isinstance(key, str) or len(key) <= 40 else repr(key[:37] + "...")
    return text if len(text) <= 60 else text[:57] + "..."


def _unknown(loader: Yaml12Loader, node: Node) -> Any:
    raise ConstructorError(None, None, f"unsupported tag {node.tag[:60]!r} (task files use plain YAML 1.2 values)",
                           node.start_mark)


for _tag, _constructor in (("null", _null), ("bool", _bool), ("int", _int), ("float", _float), ("str", _str),
                           ("seq", _seq), ("map", _map)):
    Yaml12Loader.add_constructor(TAG + _tag, _constructor)
Yaml12Loader.add_constructor(None, _unknown)

for _tag, _pattern, _first in (
    ("null", NULL, ["~", "n", "N", ""]),
    ("bool", BOOL, list("tTfF")),
    ("int", INT, list("-+0123456789")),
    ("float", FLOAT, list("-+.0123456789")),
    ("merge", MERGE, ["<"]),
):
    Yaml12Loader.add_implicit_resolver(TAG + _tag, _pattern, _first)


def load_yaml(text: str) -> Any:
    """Parse YAML text with ``Yaml12Loader`` (no Python objects, YAML 1.2 core scalars, bounded).

    Raises
    ------
    yaml.YAMLError
        Syntax errors, duplicate keys, unsupported tags, and documents past the bounds above.
    """
    try:
        return yaml.load(text, Loader=Yaml12Loader)  # a SafeLoader subclass
    except RecursionError:  # defence in depth: MAX_DEPTH should stop this first
        raise ComposerError(None, None, "the document is nested too deeply", None) from None
