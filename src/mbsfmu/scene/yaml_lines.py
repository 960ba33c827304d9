"""Safe YAML reading that remembers the line of every key and list item, for errors that point at the file."""

import yaml

from ..errors import ModelError


class Map(dict):
    """A YAML mapping with `line` (its own) and `lines[key]` (the line of each key)."""

    line = None
    lines = {}


class Seq(list):
    """A YAML sequence with `line` and `lines[i]`."""

    line = None
    lines = {}


class _Loader(yaml.SafeLoader):
    """SafeLoader (no object-constructing tags) that keeps line numbers and refuses duplicate keys."""


def _construct_mapping(loader, node):
    out = Map()
    out.line, out.lines = node.start_mark.line + 1, {}
    loader.flatten_mapping(node)
    path = loader.__dict__.setdefault("key_path", [])  # keys of the enclosing mappings, for messages
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if not isinstance(key, (str, int, float)):
            raise ModelError("a mapping key must be a plain name", line=key_node.start_mark.line + 1)
        key = str(key)
        if key in out:
            raise ModelError(f"duplicate key '{key}' (first given at line {out.lines[key]})", line=key_node.start_mark.line + 1,
                             key=_join(path + [key]), hint="each key may appear only once in a mapping; body names must be unique")
        path.append(key)
        out[key] = loader.construct_object(value_node, deep=True)
        path.pop()
        out.lines[key] = key_node.start_mark.line + 1
    return out


def _join(path):
    return ".".join(path).replace(".[", "[")


def _construct_sequence(loader, node):
    path = loader.__dict__.setdefault("key_path", [])
    items = []
    for i, child in enumerate(node.value):
        path.append(f"[{i}]")
        items.append(loader.construct_object(child, deep=True))
        path.pop()
    out = Seq(items)
    out.line = node.start_mark.line + 1
    out.lines = {i: child.start_mark.line + 1 for i, child in enumerate(node.value)}
    return out


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, _construct_sequence)


def read_yaml(text, file=None):
    """Parse YAML text safely into Map/Seq trees; any YAML problem becomes a ModelError with its line."""
    loader = _Loader(text)
    try:
        return loader.get_single_data()
    except ModelError as e:
        raise ModelError(e.message, file=file, line=e.line, key=e.key, hint=e.hint) from None
    except yaml.constructor.ConstructorError as e:
        mark = e.problem_mark
        raise ModelError(f"{e.problem}", file=file, line=mark.line + 1 if mark else None,
                         key=_join(loader.__dict__.get("key_path", [])) or None,
                         hint="tags that construct objects are not allowed; use plain YAML values") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        problem = getattr(e, "problem", None) or str(e)
        raise ModelError(f"invalid YAML: {problem}", file=file, line=mark.line + 1 if mark else None) from None
    finally:
        loader.dispose()
