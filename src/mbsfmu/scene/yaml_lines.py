"""Safe, bounded YAML reading that remembers the line of every key and list item, for errors that point at the file.

Bounded work for any text: the document size, the nesting depth and the nodes that aliases add (counted on the
node graph before anything is constructed, so an alias bomb costs nothing) are limited; long scalars and integer
literals are refused before conversion; strings that an FMU's XML cannot hold and YAML 1.1 booleans as keys
(`on:`, `off:`, `yes:`) are refused with their line.
"""

import re

import yaml
from yaml.composer import ComposerError
from yaml.constructor import SafeConstructor
from yaml.events import AliasEvent, MappingStartEvent, ScalarEvent, SequenceStartEvent, StreamEndEvent
from yaml.nodes import MappingNode, ScalarNode, SequenceNode
from yaml.resolver import Resolver

from ..errors import ModelError
from .. import limits

try:  # libyaml's event parser (not its composer, whose recursion has no depth limit) when it is there
    from yaml._yaml import CParser as _Parser
except ImportError:  # pure-Python PyYAML
    from yaml.parser import Parser
    from yaml.reader import Reader
    from yaml.scanner import Scanner

    class _Parser(Reader, Scanner, Parser):
        def __init__(self, stream):
            Reader.__init__(self, stream)
            Scanner.__init__(self)
            Parser.__init__(self)

# XML 1.0 characters (what modelDescription.xml can carry); anything else, lone surrogates included, is refused
_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


class Map(dict):
    """A YAML mapping with `line` (its own) and `lines[key]` (the line of each key)."""

    __slots__ = ("line", "lines")  # no instance dict: a 10,000-body scene has 180,000 of these and Seq

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.line, self.lines = None, _NO_LINES


class Seq(list):
    """A YAML sequence with `line` and `lines[i]`."""

    __slots__ = ("line", "lines")

    def __init__(self, *args):
        super().__init__(*args)
        self.line, self.lines = None, _NO_LINES


_NO_LINES = {}  # lines of a Map or Seq made in code, not read (never changed: such trees get their own dicts)


def _line(node):
    return node.start_mark.line + 1


class _Loader(SafeConstructor, Resolver, _Parser):
    """Parser events → nodes (an iterative, depth-limited composer) → Map/Seq/scalars (safe constructors only)."""

    def __init__(self, text):
        _Parser.__init__(self, text)
        SafeConstructor.__init__(self)
        Resolver.__init__(self)
        self.key_path, self.tags, self.nodes, self.open_ = [], {}, 0, []
        self.anchored = set()  # ids of the nodes with an anchor
        self._line_marks = {}  # line → one shared mark: messages need only the line, and a node's own two marks made
        # up half the memory of a large scene (a 10,000-body chain: 800,000 marks, 58 MiB); (line, n) → lines of a list

    def _mark(self, mark):
        line = mark.line
        if line not in self._line_marks:
            self._line_marks[line] = yaml.error.Mark(mark.name, 0, line, 0, None, None)
        return self._line_marks[line]

    def get_single_node(self):
        """The document's node graph, as yaml.composer builds it, without recursion (so no depth can crash it)."""
        self.get_event()  # stream start
        root = None
        if not self.check_event(StreamEndEvent):
            self.get_event()  # document start
            root = self._compose()
            self.get_event()  # document end
        if not self.check_event(StreamEndEvent):
            raise ComposerError(None, None, "expected a single document in the stream", self.get_event().start_mark)
        self.get_event()
        return root

    def _compose(self):
        anchors, open_ = {}, []  # open_: (node, its children so far) of unfinished collections
        self.open_ = open_
        get_event, marks, mark_of, tags = self.get_event, self._line_marks, self._mark, self.tags
        max_nodes, max_depth, max_entries = limits.NODES, limits.DEPTH, limits.ENTRIES
        while True:
            event = get_event()
            kind = type(event)
            if kind is ScalarEvent:
                if len(event.value) > limits.SCALAR_CHARS:
                    raise ModelError(f"a value of {len(event.value):,} characters (at most {limits.SCALAR_CHARS:,})", line=_line(event))
                mark = marks.get(event.start_mark.line) or mark_of(event.start_mark)
                tag = event.tag
                if tag in (None, "!"):
                    key = (event.value, event.implicit)
                    tag = tags.get(key)
                    if tag is None:  # scenes repeat their scalars (0, 1.0, revolute): resolve each text once
                        tag = tags[key] = self.resolve(ScalarNode, event.value, event.implicit)
                node = ScalarNode(tag, event.value, mark, mark, event.style)
                starts = False
            elif kind is AliasEvent:
                if event.anchor not in anchors:
                    raise ComposerError(None, None, f"found undefined alias {event.anchor!r}", event.start_mark)
                node, starts = anchors[event.anchor], False
            elif kind is SequenceStartEvent or kind is MappingStartEvent:
                if len(open_) >= max_depth:
                    raise ModelError(f"nested more than {max_depth} levels deep", line=_line(event))
                seq = kind is SequenceStartEvent
                node_kind, default = (SequenceNode, self.DEFAULT_SEQUENCE_TAG) if seq else (MappingNode, self.DEFAULT_MAPPING_TAG)
                tag = default if event.tag in (None, "!") else event.tag
                node = node_kind(tag, [], mark_of(event.start_mark), None, flow_style=event.flow_style)
                starts = True
            else:  # the end of the innermost collection
                node, children = open_.pop()
                node.end_mark = mark_of(event.end_mark)
                if type(node) is MappingNode:
                    node.value = list(zip(children[::2], children[1::2]))
                if not open_:
                    return node
                continue
            self.nodes += 1
            if self.nodes > max_nodes:
                raise ModelError(f"more than {max_nodes:,} values in one scene", line=_line(event),
                                 hint="put large nodal data in an .npz file next to the scene")
            if event.anchor is not None and kind is not AliasEvent:
                if event.anchor in anchors:
                    raise ComposerError(None, None, f"found duplicate anchor {event.anchor!r}", event.start_mark)
                anchors[event.anchor] = node
                self.anchored.add(id(node))
            if open_:
                parent, children = open_[-1]
                if len(children) >= max_entries * (1 if type(parent) is SequenceNode else 2):
                    raise ModelError(f"a list or mapping of more than {max_entries:,} entries", line=_line(event),
                                     key=self.compose_path(len(open_) - 1),
                                     hint="scenes hold at most that many bodies, forces, outputs or parameters; large nodal data belong in an .npz")
                children.append(node)
            elif not starts:
                return node
            if starts:
                open_.append((node, node.value if type(node) is SequenceNode else []))

    def compose_path(self, levels=None):
        """The key path (`bodies.arm.joint`, `forces[3]`) of the place the composer has reached, for errors met there
        (of the collection at `levels` - 1 deep, when given)."""
        parts = []
        for level, (node, children) in enumerate(self.open_[:levels]):
            last = level == len(self.open_) - 1
            if isinstance(node, SequenceNode):
                parts.append(f"[{len(children) if last else len(children) - 1}]")
            elif children:
                key = children[2 * ((len(children) - 1) // 2)]
                parts.append(key.value if isinstance(key, ScalarNode) else "?")
        return _join(parts) or None

    def construct_object(self, node, deep=False):
        """As SafeConstructor's, but a value its constructor cannot convert (`!!float abc`, `!!map [1]`) is a
        ModelError at the node's line and key path; and the node graph is let go as it is built into values (a
        scalar is not cached, a collection nobody else refers to drops its children): it never lives whole next to
        the values (a 10,000-body chain: 58 MiB of nodes)."""
        try:
            if type(node) is ScalarNode:  # a scalar has no children to recurse into: its constructor, directly
                constructor = self.yaml_constructors.get(node.tag)
                if constructor is not None:
                    return constructor(self, node)
                data = super().construct_object(node, deep)
                self.constructed_objects.pop(node, None)
                return data
            data = super().construct_object(node, deep)
            if id(node) not in self.anchored:  # an anchor's children may be merged (<<) into another mapping
                node.value = []
            return data
        except (ModelError, yaml.YAMLError):
            raise
        except (ValueError, TypeError, AttributeError, ArithmeticError) as e:
            raise ModelError(f"the value cannot be read as {node.tag.rsplit(':', 1)[-1]} ({type(e).__name__})", line=_line(node),
                             key=_join(self.key_path) or None, hint="use plain YAML values: numbers, text, lists and mappings") from None


def _check_expansion(root, anchored=frozenset()):
    """Depth and size of the node graph with aliases expanded (each shared node counted once per use).

    Linear in the distinct nodes: the expanded size of a node is memoized; a recursive alias exceeds the depth.
    Errors name the key path of the node (`stack`: the keys and indices walked down to it).
    """
    size, distinct, open_, stack = {}, [0], set(), []

    def fail(message, node, hint=None):
        raise ModelError(message, line=_line(node), key=_join(stack) or None, hint=hint)

    def walk(node, depth):
        if id(node) in open_:
            fail("an alias refers to a node that contains it", node, "recursive data cannot be a scene")
        if depth > limits.DEPTH:
            fail(f"nested more than {limits.DEPTH} levels deep (aliases expanded)", node, "a scene needs a few levels; flatten the data")
        if id(node) in size:
            return size[id(node)]
        distinct[0] += 1
        if isinstance(node, SequenceNode):
            children = [(f"[{i}]", c) for i, c in enumerate(node.value)]
        elif isinstance(node, MappingNode):
            children = [(c, n) for k, v in node.value for c, n in ((None, k), (k.value if isinstance(k, ScalarNode) else "?", v))]
        else:
            children = ()
        open_.add(id(node))
        n = 1
        for key, child in children:
            if key is not None:
                stack.append(key)
            n += walk(child, depth + 1)
            if key is not None:
                stack.pop()
        open_.discard(id(node))
        if n > distinct[0] + limits.ALIAS_NODES:
            fail(f"aliases expand this document beyond {limits.ALIAS_NODES:,} extra values", node,
                 "an alias bomb? use anchors and aliases only for small shared values")
        if id(node) in anchored:  # only an anchor's node is reached twice: memoized (each other once, not kept)
            size[id(node)] = n
        return n

    walk(root, 1)


def _construct_mapping(loader, node):
    out = Map()
    out.line, out.lines = _line(node), {}
    loader.flatten_mapping(node)
    path = loader.key_path  # keys of the enclosing mappings, for messages
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if isinstance(key, bool):
            raise ModelError(f"the key '{key_node.value}' reads as the boolean {key} (YAML 1.1)", line=_line(key_node),
                             key=_join(path + [key_node.value]), hint=f"quote it: \"{key_node.value}\":")
        if not isinstance(key, (str, int, float)):
            raise ModelError("a mapping key must be a plain name", line=_line(key_node), key=_join(path) or None)
        key = str(key)
        if key in out:
            raise ModelError(f"duplicate key '{key}' (first given at line {out.lines[key]})", line=_line(key_node),
                             key=_join(path + [key]), hint="each key may appear only once in a mapping; body names must be unique")
        path.append(key)
        out[key] = loader.construct_object(value_node, deep=True)
        path.pop()
        out.lines[key] = _line(key_node)
    return out


def _join(path):
    return ".".join(path).replace(".[", "[")


def _construct_sequence(loader, node):
    path = loader.key_path
    items = []
    for i, child in enumerate(node.value):
        path.append(f"[{i}]")
        items.append(loader.construct_object(child, deep=True))
        path.pop()
    out = Seq(items)
    out.line = line = _line(node)
    if all(child.start_mark.line + 1 == line for child in node.value):
        # a list written on one line (a vector, an inertia row): one lines dict per line and length, shared (never
        # changed: a tree that needs other lines gets new dicts), as a 10,000-body chain has 120,000 such lists
        out.lines = loader._line_marks.setdefault((line, len(items)), dict.fromkeys(range(len(items)), line))
    else:
        out.lines = {i: _line(child) for i, child in enumerate(node.value)}
    return out


def _construct_str(loader, node):
    text = loader.construct_scalar(node)
    bad = _NOT_XML.search(text)
    if bad:
        raise ModelError(f"the text holds the character U+{ord(bad.group()):04X}, which an FMU's XML cannot carry",
                         line=_line(node), key=_join(loader.key_path) or None, hint="remove control characters and lone surrogates")
    return text


class Date(str):
    """A YAML 1.1 timestamp (`2024-01-01`), kept as the text it was written as; never a number (not 2024-1-1)."""


def _construct_date(loader, node):
    return Date(_construct_str(loader, node))


# YAML 1.1 reads 1:30 as 90 (base 60) and 010 as 8 (octal): surprises, not numbers a scene means
_SURPRISING_NUMBER = re.compile(r"[-+]?(?:[0-9][0-9_]*(?::[0-5]?[0-9])+(?:\.[0-9_]*)?|0[0-7_]+)")


def _refuse_surprise(loader, node):
    if not node.style and _SURPRISING_NUMBER.fullmatch(node.value):  # plain, not quoted
        raise ModelError(f"'{node.value}' reads as a YAML 1.1 {'base-60' if ':' in node.value else 'octal'} number", line=_line(node),
                         key=_join(loader.key_path) or None, hint=f"write it in decimal, or quote it if it is text: \"{node.value}\"")


def _construct_int(loader, node):
    if node.value.isdigit() and (node.value[0] != "0" or len(node.value) == 1) and len(node.value) <= 18:
        return int(node.value)  # the common case (0, 3, 250): plain decimal digits, nothing to refuse
    if len(node.value) > limits.INT_CHARS:
        raise ModelError(f"an integer of {len(node.value):,} characters (at most {limits.INT_CHARS})", line=_line(node),
                         key=_join(loader.key_path) or None, hint="write large numbers as floats, e.g. 1.0e30")
    _refuse_surprise(loader, node)
    return SafeConstructor.construct_yaml_int(loader, node)


def _construct_float(loader, node):
    _refuse_surprise(loader, node)
    return SafeConstructor.construct_yaml_float(loader, node)


def _refuse_tag(loader, node):
    raise ModelError(f"the YAML tag {node.tag} is not supported", line=_line(node), key=_join(loader.key_path) or None,
                     hint="use plain YAML values: numbers, text, lists and mappings")


_Loader.add_constructor(Resolver.DEFAULT_MAPPING_TAG, _construct_mapping)
_Loader.add_constructor(Resolver.DEFAULT_SEQUENCE_TAG, _construct_sequence)
_Loader.add_constructor("tag:yaml.org,2002:str", _construct_str)
_Loader.add_constructor("tag:yaml.org,2002:timestamp", _construct_date)  # a date stays the text it was written as
_Loader.add_constructor("tag:yaml.org,2002:int", _construct_int)
_Loader.add_constructor("tag:yaml.org,2002:float", _construct_float)
# YAML 1.1 (PyYAML) reads a float only with a dot and a signed exponent: 2.1e11, 1e-3 and 5E+2 would be text.  A
# plain scalar that is a decimal literal with an exponent is a float, as YAML 1.2 reads it (inf and nan stay .inf, .nan)
FLOAT_LITERAL = re.compile(r"[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")
_Loader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"),
                              list("-+.0123456789"))
for _tag in ("binary", "set", "omap", "pairs"):
    _Loader.add_constructor(f"tag:yaml.org,2002:{_tag}", _refuse_tag)


def read_yaml(text, file=None):
    """Parse YAML text safely into Map/Seq trees; any YAML problem becomes a ModelError with its line."""
    if len(text) > limits.DOCUMENT_BYTES:
        raise ModelError(f"the scene is {len(text):,} characters long (at most {limits.DOCUMENT_BYTES:,})", file=file,
                         hint="put large nodal data in an .npz file next to the scene")
    bad = _NOT_XML.search(text)
    if bad:
        raise ModelError(f"the file holds the character U+{ord(bad.group()):04X}, which neither YAML nor an FMU's XML allows",
                         file=file, line=text.count("\n", 0, bad.start()) + 1, hint="remove control characters")
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        if loader.anchored:  # without anchors the composer's own depth and node limits already bound the graph
            _check_expansion(node, loader.anchored)
        return loader.construct_document(node)
    except ModelError as e:
        raise ModelError(e.message, file=file, line=e.line, key=e.key or loader.compose_path(), hint=e.hint) from None
    except yaml.constructor.ConstructorError as e:
        mark = e.problem_mark
        raise ModelError(f"{e.problem}", file=file, line=mark.line + 1 if mark else None,
                         key=_join(loader.key_path) or None,
                         hint="tags that construct objects are not allowed; use plain YAML values") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        problem = getattr(e, "problem", None) or str(e)
        if "nesting depth" in problem:  # libyaml's own depth limit (PyYAML >= 6.0.4) may answer before ours
            raise ModelError(f"nested more than {limits.DEPTH} levels deep", file=file, line=mark.line + 1 if mark else None,
                             key=loader.compose_path(), hint="a scene needs a few levels; flatten the data") from None
        raise ModelError(f"invalid YAML: {problem}", file=file, line=mark.line + 1 if mark else None, key=loader.compose_path(),
                         hint="check the indentation (spaces, not tabs), colons and brackets at this line") from None
    finally:
        loader.dispose()
