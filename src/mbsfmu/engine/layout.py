"""The compiled scene's layout as C declares it: mbs_layout.h, read with a strict parser.

mbs_layout.h is the one declaration of every section id, table field, type code and size (X-macro lists, as
MuJoCo's mjxmacro.h); this module gives Python the same numbers, so compiler/scene_file.py, compiler/elastic_tables.py and build.py
write no constant of their own. Every name of the header becomes a module attribute (`layout.IB_POS`), and
each list a tuple of its entries' arguments (`LISTS["MBS_METHODS"]`). A line the parser does not know is an
error, never skipped: a constant it missed would silently differ from C's.
Standard library only (it ships inside pythonfmu FMUs with the rest of engine/).
"""

import re
from pathlib import Path

HEADER = Path(__file__).with_name("mbs_layout.h")

_GENERATORS = ("MBS_CODE", "MBS_FIELD", "MBS_VALUE")
_DEFINE = re.compile(r"#define ([A-Z][A-Z0-9_]*) (-?\d+)")
_LIST = re.compile(r"#define (MBS_[A-Z0-9_]+)\(X\)(.*)")
_ENTRY = re.compile(r"\s*X\(([^()]*)\)")
_ARG = re.compile(r'\s*([A-Za-z_][A-Za-z0-9_]*|-?\d+|"[a-z0-9_.]*")\s*')
_TEXT = re.compile(r'#define ([A-Z][A-Z0-9_]*) "([A-Za-z0-9_.]*)"')
_ENUM = re.compile(r"enum \{ (MBS_[A-Z0-9_]+)\((MBS_CODE|MBS_FIELD|MBS_VALUE)\)(?: ([A-Z][A-Z0-9_]*))? \};")
_SKIP = re.compile(r"#ifndef MBS_LAYOUT_H|#define MBS_LAYOUT_H|#endif|#define (MBS_CODE|MBS_FIELD|MBS_VALUE)_?\(")


class LayoutError(ValueError):
    pass


def _logical_lines(text):
    """(line number, text) with comments removed and backslash continuations joined."""
    text = re.sub(r"/\*.*?\*/", lambda m: " " + "\n" * m.group(0).count("\n"), text, flags=re.S)
    out, buf, start = [], "", 0
    for n, line in enumerate(text.split("\n"), 1):
        if not buf:
            start = n
        if line.rstrip().endswith("\\"):
            buf += line.rstrip()[:-1] + " "
            continue
        buf += line
        if buf.strip():
            out.append((start, " ".join(buf.split())))
        buf = ""
    return out


def _arg(text, where):
    m = _ARG.fullmatch(text)
    if not m:
        raise LayoutError(f"{where}: argument {text.strip()!r} is not a NAME, an integer or a \"string\"")
    a = m.group(1)
    return a[1:-1] if a.startswith('"') else int(a) if a.lstrip("-").isdigit() else a


def parse(text, source="mbs_layout.h"):
    """(constants {name: int or text}, lists {list name: tuple of entry tuples}) of a layout header's text."""
    consts, lists = {}, {}

    def define(name, value, where):
        if name in consts:
            raise LayoutError(f"{where}: {name} declared twice")
        consts[name] = value

    for n, line in _logical_lines(text):
        where = f"{source}:{n}"
        if _SKIP.match(line):
            continue
        if m := _LIST.fullmatch(line):
            body, entries = m.group(2), []
            pos = 0
            while pos < len(body):
                e = _ENTRY.match(body, pos)
                if not e:
                    if body[pos:].strip():
                        raise LayoutError(f"{where}: {m.group(1)}: expected X(...) at {body[pos:pos + 30]!r}")
                    break
                entries.append(tuple(_arg(a, where) for a in e.group(1).split(",")))
                pos = e.end()
            if not entries or any(not isinstance(e[0], str) for e in entries):
                raise LayoutError(f"{where}: {m.group(1)}: every entry starts with its NAME")
            lists[m.group(1)] = tuple(entries)
        elif m := _DEFINE.fullmatch(line):
            define(m.group(1), int(m.group(2)), where)
        elif m := _TEXT.fullmatch(line):
            define(m.group(1), m.group(2), where)
        elif m := _ENUM.fullmatch(line):
            name, gen, total = m.groups()
            if name not in lists:
                raise LayoutError(f"{where}: enum of {name}, which is not declared above")
            pos = 0
            for entry in lists[name]:
                if gen == "MBS_CODE":
                    define(entry[0], pos, where)
                    pos += 1
                elif len(entry) < 2 or not isinstance(entry[1], int):
                    raise LayoutError(f"{where}: {entry[0]}: {gen} needs an integer second argument")
                elif gen == "MBS_FIELD":
                    define(entry[0], pos, where)
                    pos += entry[1]
                else:
                    define(entry[0], entry[1], where)
            if total:
                if gen == "MBS_VALUE":
                    raise LayoutError(f"{where}: a list of values has no total")
                define(total, pos, where)
        else:
            raise LayoutError(f"{where}: not a line of the layout's grammar (see the header's first comment): {line[:60]!r}")
    return consts, lists


def names(list_name, arg=1):
    """{an entry's argument `arg` (its name in scenes or Python): its code} of a list."""
    return {e[arg]: CONSTANTS[e[0]] for e in LISTS[list_name]}


CONSTANTS, LISTS = parse(HEADER.read_text())
globals().update(CONSTANTS)
METHODS = tuple(e[1] for e in LISTS["MBS_METHODS"])  # integrator names, in code order
ADAPTIVE = tuple(e[1] for e in LISTS["MBS_METHODS"] if e[3] == "tolerance")  # accuracy from rtol, atol
FIXED_STEP = tuple(e[1] for e in LISTS["MBS_METHODS"] if e[3] == "step")  # accuracy from integrator.step
SECTION_ROW = "<" + "".join({4: "i", 8: "q"}[e[1]] for e in LISTS["MBS_SECTION_ROW"])  # struct format of a row


def elastic_array_sizes(n, stiffening):
    """{ED_* name: numbers} of one elastic body's arrays in S_ELASTIC_D, in their order, for n modes."""
    return {e[0]: e[1] + e[2] * n + e[3] * n * n for e in LISTS["MBS_ELASTIC_D"] if stiffening or not e[4]}
