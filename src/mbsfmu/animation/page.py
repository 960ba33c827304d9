"""One self-contained HTML page: the template, the vendored three.js modules and the viewer inlined as
text, the frames as base64 float arrays in a JSON block. Opens from disk with no network access."""

import base64
import json
import re
from pathlib import Path

import numpy as np

from ..version import __version__

THREE_VERSION = "0.180.0"
_HERE = Path(__file__).parent
_VENDOR = _HERE / "vendor" / "three"


def _b64(a, dtype):
    return base64.b64encode(np.ascontiguousarray(a, dtype=dtype).tobytes()).decode("ascii")


def _inline(text, what):
    """Text placed inside a <script> element must not end it early."""
    low = text.lower()
    if "</script" in low or "<!--" in low:
        raise ValueError(f"{what} cannot be inlined: it contains '</script' or '<!--'")
    return text


def _json(obj):
    # '<' escaped everywhere, so no text from the scene can close the <script> element
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")


def render(name, description, t, F, scene):
    """The page's HTML for frames F (rows at times t) and the static scene description."""
    for b in scene["bodies"]:
        for s in b["shapes"]:
            if "triangles" in s:
                s["triangles"] = _b64(s["triangles"].reshape(-1), "<f4")
    data = {"name": name, "description": description, "t": _b64(t, "<f8"), "frames": _b64(F.reshape(-1), "<f4"),
            "stride": F.shape[1], "scene": scene}
    vendor = {k: _inline((_VENDOR / f).read_text(encoding="utf-8"), f) for k, f in
              (("@THREE_CORE@", "three.core.min.js"), ("@THREE_MODULE@", "three.module.min.js"),
               ("@ORBIT_CONTROLS@", "OrbitControls.js"))}
    html = (_HERE / "page.html").read_text(encoding="utf-8")
    title = name.replace("&", "&amp;").replace("<", "&lt;")
    fills = {"@VERSION@": __version__, "@THREE_VERSION@": THREE_VERSION, "@TITLE@": title, "@DATA@": _json(data),
             "@VIEWER@": _inline((_HERE / "viewer.js").read_text(encoding="utf-8"), "viewer.js"), **vendor}
    return re.sub(r"@[A-Z_]+@", lambda m: fills[m.group(0)], html)  # one pass: inserted text is never rescanned
