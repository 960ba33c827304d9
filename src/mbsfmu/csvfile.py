"""CSV tables the commands read: input CSVs (`--input`) and result CSVs (`mbsfmu simulate --csv`). A header row
whose first column is `time`, then one finite number per cell: a cell that is not a number is refused with its
row and column (read as NaN it would reach the FMU as a discarded step, or be drawn as nothing)."""

import csv
import io
import math

import numpy as np

from . import limits


def read_csv(path, what):
    """A CSV → (column names after 'time', times, structured array with every column by name). `what` names
    the table in messages ('input', 'result')."""
    try:
        with limits.open_regular(path) as f:
            header, rows = _rows(csv.reader(io.TextIOWrapper(f, encoding="utf-8", newline="")), path, what)
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise ValueError(f"{path}: cannot read the {what} CSV: {getattr(e, 'strerror', None) or e}") from None
    data = np.array(rows, dtype=[(n, float) for n in header]).reshape(-1)
    t = data["time"]
    if len(t) == 0 or np.any(np.diff(t) < 0):
        raise ValueError(f"{path}: the {what} CSV needs at least one row, with non-decreasing times")
    return header[1:], t, data


def _rows(reader, path, what):
    """(header, rows of floats); lines starting with '#' and empty lines are skipped."""
    header, rows = None, []
    for row in reader:
        if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
            continue
        where = f"{path}:{reader.line_num}"
        if header is None:
            header = [c.strip() for c in row]
            if header[0] != "time":
                raise ValueError(f"{where}: the first column of the {what} CSV must be 'time' (got '{header[0]}')")
            if len(set(header)) < len(header):
                raise ValueError(f"{where}: a column name appears twice in the {what} CSV")
            continue
        if len(row) != len(header):
            raise ValueError(f"{where}: {len(row)} values, but the header names {len(header)} columns")
        if len(rows) >= limits.RESULT_POINTS:
            raise ValueError(f"{path}: more than {limits.RESULT_POINTS:,} rows")
        rows.append(tuple(_number(c, name, where) for c, name in zip(row, header)))
    if header is None:
        raise ValueError(f"{path}: the {what} CSV is empty (expected a header row: time,<names>)")
    return header, rows


def _number(cell, column, where):
    try:
        v = float(cell)
    except ValueError:
        v = None
    if v is None or not math.isfinite(v):
        shown = f"'{cell.strip()}'" if cell.strip() else "an empty cell"
        raise ValueError(f"{where}: column '{column}': {shown} is not a finite number")
    return v


def check_inputs(path, names, valid, model_name):
    """Every column after 'time' names an input of the model."""
    unknown = [n for n in names if n not in valid]
    if unknown:
        raise ValueError(f"{path}: not inputs of {model_name}: {', '.join(unknown)} (inputs: {', '.join(sorted(valid)) or 'none'})")


def check_fmu_inputs(path, names, md):
    """check_inputs against an FMU's modelDescription (fmpy's). An FMI 3.0 array input takes no column: one
    number per cell cannot fill it, and fmpy's input table cannot mix arrays and scalars; a column under an
    element's FMI 2.0 name (``T_motor.y``, which FMI 3.0 hosts do not know) is refused naming the element."""
    from .compiler.variables import fmi2_elements
    inputs = [v for v in md.modelVariables if v.causality == "input"]
    arrays = {v.name: fmi2_elements(v.description)[1] or [] for v in inputs if getattr(v, "dimensions", None)}
    element = {e: (a, k) for a, es in arrays.items() for k, e in enumerate(es, 1)}
    for n in names:
        if n in arrays or n in element:
            a, k = element.get(n, (n, None))
            what = f"is FMI 2.0's name of {a}[{k}], an element of" if k else "is"
            there = n if k else ", ".join(arrays[a]) or "scalars"
            raise ValueError(f"{path}: column '{n}' {what} the array input {a} of {md.modelName} (an FMI "
                             f"{md.fmiVersion} FMU); an input CSV sets scalar inputs only: give it through the scene's "
                             f"FMI 2.0 FMU (mbsfmu build without --fmi 3), where it is {there}")
    check_inputs(path, names, {v.name for v in inputs if v.name not in arrays}, md.modelName)
