"""Errors users see: scene errors (ModelError) and run-time integration failures."""

import unicodedata

_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape(ch):
    """One character as the terminal should show it."""
    if ch in _NAMED:
        return _NAMED[ch]
    if unicodedata.category(ch) in ("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"):
        # controls (C0, DEL, C1: ESC starts terminal commands), format characters (bidi overrides, zero
        # widths), lone surrogates, private/unassigned code points and line separators
        return f"\\x{ord(ch):02x}" if ord(ch) < 0x100 else f"\\u{ord(ch):04x}" if ord(ch) < 0x10000 else f"\\U{ord(ch):08x}"
    return ch


def printable(text):
    """`text` with every character that could act on a terminal or reorder a line written as an escape
    (\\r, \\x1b, \\u202e, ...): what a file holds is shown, never obeyed. Plain text comes back unchanged."""
    text = str(text)
    if text.isprintable():
        return text
    return "".join(_escape(ch) for ch in text)


class ModelError(ValueError):
    """A scene that cannot be built: names the file, line, key path and what would be valid."""

    def __init__(self, message, file=None, line=None, key=None, hint=None):
        self.file, self.line, self.key, self.hint = file, line, key, hint
        self.message = message
        # every part may quote the file (its name, keys, values): all of them escaped, here, once
        where = ""
        if file is not None:
            where = f"{printable(file)}:{line}: " if line is not None else f"{printable(file)}: "
        elif line is not None:
            where = f"line {line}: "
        text = where + (f"{printable(key)}: " if key else "") + printable(message)
        if hint:
            text += f" ({printable(hint)})"
        super().__init__(text)


class IntegrationError(RuntimeError):
    """The integrator could not advance (tolerance not met, non-finite state or input)."""

    def __init__(self, message, t=None):
        self.t, self.message = t, message
        super().__init__(message if t is None else f"t={t:.9g}: {message}")


class EngineUnavailable(RuntimeError):
    """No compiled engine: no C compiler, or it failed."""
