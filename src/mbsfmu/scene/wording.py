"""How a scene's messages quote what the file gave and suggest what would be valid (shared by every reader)."""

import difflib
import json

from .yaml_lines import Date


def shown(value):
    """A YAML value as the file gave it, for messages: what was written, never the reader's type names."""
    if value is None:
        return "nothing (an empty value or null)"
    if isinstance(value, bool):  # YAML 1.1: yes/no, true/false, on/off
        return f"{'true' if value else 'false'} (YAML reads yes/no, on/off and true/false so)"
    if isinstance(value, Date):
        return f"the date '{value}'"
    if isinstance(value, list):
        return f"a list ({brief(json.dumps(value, default=str))})"
    if isinstance(value, dict):
        return f"a mapping ({brief(json.dumps(value, default=str))})"
    return f"'{brief(str(value))}'" if isinstance(value, str) else brief(repr(value))


def brief(text, n=60):
    return text if len(text) <= n else text[:n - 5] + " … "


def suggest(word, valid):
    close = difflib.get_close_matches(str(word), list(valid), n=1)
    hint = f"did you mean '{close[0]}'? " if close else ""
    return hint + "valid: " + ", ".join(str(v) for v in valid)
