"""mbsfmu animate: poses against closed forms, the page's contents, and the page in a real headless chromium
(loads without console errors, draws, moves, and puts a shape where the camera model says it must be)."""

import base64
import fcntl
import io
import json
import math
import os
import re
import select
import shutil
import struct
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.animation import decimate, frames
from mbsfmu.animation.mesh import read_mesh
from mbsfmu.cli import main
from mbsfmu.compiler.model import Model

MODELS = Path(__file__).resolve().parent.parent / "models"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
W, H = 800, 600
BACKGROUND = np.array([0xf3, 0xf4, 0xf6])


def page_data(path):
    html = Path(path).read_text(encoding="utf-8")
    data = json.loads(re.search(r'<script type="application/json" id="mbsfmu-data">(.*?)</script>', html, re.S).group(1))
    t = np.frombuffer(base64.b64decode(data["t"]), dtype="<f8")
    F = np.frombuffer(base64.b64decode(data["frames"]), dtype="<f4").reshape(len(t), data["stride"])
    return data, t, F


def quat_matrix(q):
    """Rotation matrix of a unit quaternion given as x, y, z, w (scipy's convention, as three.js's)."""
    from scipy.spatial.transform import Rotation
    return Rotation.from_quat(np.asarray(q, dtype=float)).as_matrix()


def R_y(a):
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def project(cam, p, width=W, height=H):
    """Pixel (column, row) of world point p for a perspective camera looking from cam.position at cam.target."""
    pos, target, up = (np.array(cam[k], dtype=float) for k in ("position", "target", "up"))
    z = pos - target
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    d = np.array([x, y, z]) @ (np.asarray(p, dtype=float) - pos)
    f = 1 / math.tan(math.radians(cam["fov"]) / 2)
    ndc = np.array([f * height / width * d[0] / -d[2], f * d[1] / -d[2]])
    return np.array([(ndc[0] + 1) / 2 * width, (1 - ndc[1]) / 2 * height])


# -- poses against closed forms (no browser) -------------------------------------------------------------

def test_pendulum_poses_are_rotations_about_y():
    """Each frame: rod frame = R_y(θ) at the hinge, bob at R_y(θ)·(0, 0, −L); θ from the trajectory."""
    scene = mbsfmu.load(MODELS / "pendulum.yaml")
    model = Model(scene.spec)
    theta = np.linspace(-1.0, 2.5, 7)
    _, F = frames.frames(model, theta, theta[:, None])
    for th, row in zip(theta, F):
        for i, name in enumerate(b.name for b in model.bodies):
            o, q = row[7 * i:7 * i + 3], row[7 * i + 3:7 * i + 7]
            assert np.allclose(quat_matrix(q), R_y(th), atol=1e-12)
            assert np.allclose(o, R_y(th) @ [0, 0, -0.8] if name == "bob" else 0.0, atol=1e-12)


def test_elastic_nodes_follow_the_rigid_motion_when_undeformed():
    """Flexible pendulum with q = 0: the beam's nodes lie on the hub's rotated x axis at 0.05 + k·L/10."""
    model = Model(mbsfmu.load(MODELS / "flexible_pendulum.yaml").spec)
    layout, F = frames.frames(model, [0.0, 0.0], [[0.0, 0, 0, 0], [0.7, 0, 0, 0]])
    assert layout.nodes == [11]
    nodes = F[:, 7 * len(model.bodies):].reshape(2, 11, 3)
    for th, P in zip((0.0, 0.7), nodes):
        expected = np.array([R_y(th) @ [0.05 + k / 10, 0, 0] for k in range(11)])
        assert np.allclose(P, expected, atol=1e-12)


def test_decimate_keeps_ends_and_rate():
    t = np.linspace(0, 10, 10001)
    k = decimate(t, 30)
    assert k[0] == 0 and k[-1] == len(t) - 1
    assert np.all(np.diff(t[k]) <= 1 / 30 + 1e-3) and len(k) <= 10 * 30 + 2
    assert len(decimate(t, 1e6, max_frames=500)) <= 501
    assert np.array_equal(decimate(t[:5], 60), [0, 4])  # 4 ms at 60 frames/s: the two ends
    assert np.array_equal(decimate(t[::100], 10), np.arange(101))  # samples sparser than the rate: all kept


# -- the page file -----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def pendulum_page(tmp_path_factory):
    return mbsfmu.animate(MODELS / "pendulum.yaml", tmp_path_factory.mktemp("anim") / "pendulum.html", stop=2.0)


def test_page_is_self_contained(pendulum_page):
    html = pendulum_page.read_text(encoding="utf-8")
    assert not re.search(r"<(script|link|img|iframe)[^>]+(src|href)\s*=", html, re.I), "the page loads nothing from outside"
    assert "Copyright 2010-2025 Three.js Authors" in html  # the library travels with its licence notice
    data, t, F = page_data(pendulum_page)
    assert data["name"] == "pendulum" and t[0] == 0 and abs(t[-1] - 2.0) < 1e-12
    assert np.all(np.diff(t) > 0) and np.all(np.diff(t) <= 1 / 60 + 0.01)
    assert pendulum_page.stat().st_size < 1.5e6


def test_pendulum_page_follows_the_exact_solution(pendulum_page):
    """The rod's drawn rotation against the exact large-amplitude θ(t) (float32 frames: ~1e-7)."""
    _, t, F = page_data(pendulum_page)
    angle = np.array([math.atan2(R[0, 2], R[0, 0]) for R in (quat_matrix(q) for q in F[:, 3:7])])
    assert np.max(np.abs(angle - pendulum_theta(t))) < 1e-6


def test_scene_text_cannot_close_the_script(tmp_path):
    text = (MODELS / "pendulum.yaml").read_text().replace(
        "description: >-", 'description: "</script><script>alert(1)</script> <!--"\nx_description: >-', 1)
    text = re.sub(r"\nx_description: >-\n(  .*\n)+", "\n", text)
    scene_file = tmp_path / "p.yaml"
    scene_file.write_text(text)
    html = mbsfmu.animate(scene_file, tmp_path / "p.html", stop=0.1).read_text()
    assert "alert(1)" in html and "</script><script>alert" not in html
    assert page_data(tmp_path / "p.html")[0]["description"].startswith("</script>")


def test_result_csv_is_drawn(tmp_path):
    """`mbsfmu simulate --csv` then `animate --result`: the rod's frames are R_y(θ) with θ from the CSV."""
    csv = tmp_path / "r.csv"
    assert main(["simulate", str(MODELS / "pendulum.yaml"), "--stop", "1", "--csv", str(csv)]) == 0
    out = tmp_path / "r.html"
    assert main(["animate", str(MODELS / "pendulum.yaml"), "--result", str(csv), "-o", str(out)]) == 0
    rows = np.genfromtxt(csv, delimiter=",", names=True, deletechars="")
    _, t, F = page_data(out)
    theta = np.interp(t, rows["time"], rows["y.theta"])
    assert np.all(np.isin(np.round(t, 9), np.round(rows["time"], 9)))  # frames are samples, not interpolations
    for th, row in zip(theta, F):
        assert np.allclose(quat_matrix(row[3:7]), R_y(th), atol=2e-7)  # float32
    bad = tmp_path / "bad.csv"
    bad.write_text("time,y.phi\n0,1\n")
    assert main(["animate", str(MODELS / "pendulum.yaml"), "--result", str(bad), "-o", str(out)]) == 1


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["animate", str(tmp_path / "missing.yaml"), "-o", str(tmp_path / "x.html")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: no such file") and err.count("\n") == 1


# -- shapes in the scene format ----------------------------------------------------------------------------

def _with_shape(shape, tmp_path):
    text = (MODELS / "pendulum.yaml").read_text().replace("    mass: m_bob\n", f"    mass: m_bob\n    shape: {shape}\n")
    f = tmp_path / "s.yaml"
    f.write_text(text)
    return f


@pytest.mark.parametrize("shape, key, words", [
    ("{type: spere, radius: 1}", "bodies.bob.shape.type", "did you mean 'sphere'"),
    ("{type: sphere}", "bodies.bob.shape", "missing required key 'radius'"),
    ("{type: cylinder, radius: 0.1, length: -L}", "bodies.bob.shape.length", "must be positive"),
    ("[{type: sphere, radius: 0.1}, {type: box, size: [1, 0, 1]}]", "bodies.bob.shape[1].size[1]", "positive"),
    ("{type: mesh, file: ../outside.stl}", "bodies.bob.shape.file", "outside the scene's folder"),
    ("{type: mesh, file: /etc/hostname}", "bodies.bob.shape.file", "outside the scene's folder"),
    ("{type: mesh, file: none.stl}", "bodies.bob.shape.file", "no such mesh file"),
    ("{type: mesh, file: s.yaml}", "bodies.bob.shape.file", "not a supported mesh file"),
    ("{type: sphere, radius: 0.1, color: bleu}", "bodies.bob.shape.color", "not a colour"),
    ("{type: sphere, radius: 0.1, colour: red}", "bodies.bob.shape.colour", "did you mean 'color'"),
])
def test_bad_shapes_name_file_line_and_key(tmp_path, shape, key, words):
    f = _with_shape(shape, tmp_path)
    with pytest.raises(mbsfmu.ModelError) as e:
        mbsfmu.load(f)
    assert e.value.file == str(f) and e.value.line == 28 and e.value.key == key and words in str(e.value)


def test_shape_on_an_elastic_body_is_refused(tmp_path):
    text = (MODELS / "flexible_pendulum.yaml").read_text().replace(
        "    elastic:\n", "    shape: {type: box, size: [1, 0.02, 0.005]}\n    elastic:\n", 1)
    with pytest.raises(mbsfmu.ModelError, match="drawn deformed through their nodes"):
        mbsfmu.loads(text)


TETRA = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 0], [0, 0, 1], [1, 0, 0]],
                  [[0, 0, 0], [0, 1, 0], [0, 0, 1]], [[1, 0, 0], [0, 0, 1], [0, 1, 0]]], dtype=float)


def test_mesh_files_binary_ascii_stl_and_obj(tmp_path):
    binary = tmp_path / "t.stl"
    binary.write_bytes(b"solid looks like ascii but is binary".ljust(80, b" ") + struct.pack("<I", 4)
                       + b"".join(struct.pack("<12fH", 0, 0, 0, *tri.ravel(), 0) for tri in TETRA))
    ascii_ = tmp_path / "a.stl"
    ascii_.write_text("solid t\n" + "".join("facet normal 0 0 0\n outer loop\n" + "".join(f"  vertex {x} {y} {z}\n" for x, y, z in tri)
                                            + " endloop\nendfacet\n" for tri in TETRA) + "endsolid t\n")
    obj = tmp_path / "q.obj"  # a unit square as one quad (split into two triangles) with a negative index
    obj.write_text("# square\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1/1 2/2 3/3 -1\n")
    assert np.array_equal(read_mesh(binary), TETRA) and np.array_equal(read_mesh(ascii_), TETRA)
    assert np.array_equal(read_mesh(obj), [[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]])
    broken = tmp_path / "b.obj"
    broken.write_text("v 0 0 0\nf 1 2 3\n")
    with pytest.raises(mbsfmu.ModelError, match="b.obj.*vertex that does not exist"):
        read_mesh(broken)
    fifo = tmp_path / "f.stl"   # opening a FIFO waits for a writer forever; /dev/zero never ends
    os.mkfifo(fifo)
    (tmp_path / "z.stl").symlink_to("/dev/zero")
    for special in (fifo, tmp_path / "z.stl", tmp_path):
        with pytest.raises(mbsfmu.ModelError, match="not a regular file"):
            read_mesh(special)


# -- in a real browser ---------------------------------------------------------------------------------------

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--hide-scrollbars", "--mute-audio"]


class Browser:
    """Headless chromium driven through the DevTools protocol on a pipe (the browser reads fd 3, writes fd 4;
    messages end with a NUL byte), so no websocket client is needed."""

    def __init__(self, exe, width=W, height=H):
        self.profile = tempfile.mkdtemp(prefix="mbsfmu_chromium_")
        to_chrome, self._w = os.pipe()
        self._r, from_chrome = os.pipe()
        a, b = (fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (to_chrome, from_chrome))  # clear of 3 and 4

        def child():
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen([exe, *FLAGS, f"--user-data-dir={self.profile}", "--remote-debugging-pipe",
                                      f"--window-size={width},{height}", "about:blank"],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                     pass_fds=(3, 4), preexec_fn=child)
        for fd in (to_chrome, from_chrome, a, b):
            os.close(fd)
        self._buf, self._id, self.events = b"", 0, []
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Runtime", "Log", "Page"):
            self.call(f"{domain}.enable", session=True)
        self.call("Emulation.setDeviceMetricsOverride", session=True, width=width, height=height, deviceScaleFactor=1, mobile=False)

    def call(self, method, session=False, timeout=30, **params):
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self.session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        end = time.monotonic() + timeout
        while True:
            m = self._next(end - time.monotonic())
            if m.get("id") == self._id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m["result"]
            self.events.append(m)

    def _next(self, timeout):
        while b"\0" not in self._buf:
            if not select.select([self._r], [], [], max(timeout, 0))[0]:
                raise TimeoutError("no answer from chromium")
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                raise RuntimeError("chromium closed the pipe")
            self._buf += chunk
        msg, self._buf = self._buf.split(b"\0", 1)
        return json.loads(msg)

    def errors(self):
        """Console errors and uncaught exceptions seen so far."""
        out = []
        for e in self.events:
            m, p = e.get("method"), e.get("params", {})
            if m == "Runtime.exceptionThrown":
                d = p["exceptionDetails"]
                out.append(d.get("exception", {}).get("description") or d["text"])
            elif m == "Runtime.consoleAPICalled" and p["type"] in ("error", "assert"):
                out.append(" ".join(str(a.get("value", a.get("description"))) for a in p["args"]))
            elif m == "Log.entryAdded" and p["entry"]["level"] == "error":
                out.append(p["entry"]["text"])
        return out

    def show(self, page, t, timeout=30):
        """Open page#t=<t>&ui=0, wait until it has drawn that instant → screenshot (H × W × 3 ints)."""
        self.call("Page.navigate", session=True, url=f"{Path(page).resolve().as_uri()}#t={t!r}&ui=0")
        end = time.monotonic() + timeout
        while True:
            r = self.call("Runtime.evaluate", session=True, returnByValue=True,
                          expression="window.mbsfmuView ? window.mbsfmuView.t : null")["result"].get("value")
            if r is not None and abs(r - t) <= 1e-9 * max(1.0, abs(t)):
                break
            if time.monotonic() > end:
                raise TimeoutError(f"the page did not show t={t}; errors: {self.errors()}")
            time.sleep(0.05)
        png = base64.b64decode(self.call("Page.captureScreenshot", session=True, format="png")["data"])
        from PIL import Image
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)

    def close(self):
        try:
            self.call("Browser.close", timeout=5)
            self.proc.wait(timeout=10)
        except Exception:
            self.proc.kill()
            self.proc.wait()
        os.close(self._w)
        os.close(self._r)
        shutil.rmtree(self.profile, ignore_errors=True)


@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM:
        pytest.skip("chromium is not installed (apt-get install chromium)")
    b = Browser(CHROMIUM)
    yield b
    b.close()


def changed_near(a, b, px, radius):
    """Number of pixels within `radius` of pixel px (column, row) whose colour differs between a and b."""
    rows, cols = np.ogrid[:a.shape[0], :a.shape[1]]
    near = (cols - px[0]) ** 2 + (rows - px[1]) ** 2 <= radius ** 2
    return int(np.sum(near & (np.abs(a - b).max(axis=2) > 40)))


def drawn_points(data, F):
    """World positions (frames × points × 3) of every centre-of-mass marker and every elastic node."""
    pts = []
    for i, b in enumerate(data["scene"]["bodies"]):
        if b["marker"] > 0:
            pts.append(F[:, 7 * i:7 * i + 3] + np.array([quat_matrix(q) @ b["com"] for q in F[:, 7 * i + 3:7 * i + 7]]))
    nb = len(data["scene"]["bodies"])
    n_nodes = sum(e["nodes"] for e in data["scene"]["elastic"])
    nodes = F[:, 7 * nb:7 * nb + 3 * n_nodes].reshape(len(F), n_nodes, 3)
    return np.concatenate(([np.stack(pts, axis=1)] if pts else []) + ([nodes] if n_nodes else []), axis=1)


STOP = {"spinup_beam": 3.0, "crane": 3.0, "flexible_pendulum": 1.0}  # flexible_pendulum: ~9 s of numpy-path run per simulated s
DEFAULT = ("pendulum", "robot_arm_elastic")  # one rigid, one elastic
SHIPPED = sorted(p.stem for p in MODELS.glob("*.yaml"))


@pytest.mark.parametrize("name", [n if n in DEFAULT else pytest.param(n, marks=pytest.mark.slow) for n in SHIPPED])
def test_shipped_model_page_draws_and_moves(name, browser, tmp_path):
    """Loads without console errors, draws something where the bodies are, and the picture changes where the
    point that moves most on screen was and went."""
    spec = mbsfmu.load(MODELS / f"{name}.yaml").spec
    page = mbsfmu.animate(MODELS / f"{name}.yaml", tmp_path / f"{name}.html", stop=min(spec["experiment"]["stop"], STOP.get(name, 2.0)))
    data, t, F = page_data(page)
    cam = data["scene"]["camera"]
    P = drawn_points(data, F)
    px = np.array([[project(cam, p) for p in row] for row in P])
    assert np.all((px > 0) & (px < [W, H])), "the initial camera sees everything drawn"
    k, j = np.unravel_index(np.argmax(np.linalg.norm(px - px[0], axis=2)), px.shape[:2])
    assert np.linalg.norm(px[k, j] - px[0, j]) > 5, "the motion is visible on screen"
    n_errors = len(browser.errors())
    first, later = browser.show(page, float(t[0])), browser.show(page, float(t[k]))
    assert browser.errors()[n_errors:] == []
    assert np.mean(np.abs(first - BACKGROUND).max(axis=2) > 40) > 0.001, "the canvas is not blank"
    for p in (px[0, j], px[k, j]):
        assert changed_near(first, later, p, radius=6) >= 5, f"nothing changed near pixel {p} (t = 0 and {t[k]:.3f} s)"


def _bob_box_scene(tmp_path):
    """The shipped pendulum with a magenta 6 cm box on the bob (drawing only: same motion)."""
    return _with_shape("{type: box, size: [0.06, 0.06, 0.06], color: '#ff00ff'}", tmp_path)


def pendulum_theta(t, L=0.8, m_rod=0.3, m_bob=1.0, r=0.031, g=9.81, theta0=math.pi / 6):
    """Exact angle of the shipped pendulum released from rest: θ(t) = 2 asin(k·sn(K − ω₀t, k)), k = sin(θ₀/2),
    the large-amplitude solution of I_O θ̈ = −m g d sin θ (rod about its end, bob as a solid sphere)."""
    from scipy.special import ellipj, ellipk
    I_O = m_rod * L ** 2 / 3 + m_bob * L ** 2 + 0.4 * m_bob * r ** 2
    w0 = math.sqrt((m_rod * L / 2 + m_bob * L) * g / I_O)
    k = math.sin(theta0 / 2)
    return 2 * np.arcsin(k * ellipj(ellipk(k * k) - w0 * np.asarray(t), k * k)[0])


def test_shape_lands_on_the_pixels_the_closed_form_motion_predicts(browser, tmp_path):
    """The bob's box centre follows the exact θ(t); projected with the page's camera it must land on the
    magenta pixels."""
    page = mbsfmu.animate(_bob_box_scene(tmp_path), tmp_path / "box.html", stop=1.0)
    data, _, _ = page_data(page)
    cam = data["scene"]["camera"]
    L = 0.8
    for t in (0.0, 0.37, 0.81):
        theta = pendulum_theta(t)
        img = browser.show(page, t)
        magenta = (img[..., 0] > 1.6 * img[..., 1] + 40) & (img[..., 2] > 1.6 * img[..., 1] + 40)
        rows, cols = np.nonzero(magenta)
        assert len(rows) > 100, f"no box drawn at t={t}"
        centre = R_y(theta) @ [0, 0, -L]
        corners = np.array([project(cam, centre + R_y(theta) @ (0.03 * (2 * np.array(s) - 1))) for s in np.ndindex(2, 2, 2)])
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        drawn_lo, drawn_hi = [cols.min(), rows.min()], [cols.max() + 1, rows.max() + 1]  # pixel p covers [p, p + 1)
        assert np.allclose(drawn_lo, lo, atol=1.25) and np.allclose(drawn_hi, hi, atol=1.25), \
            f"t={t}: box drawn over pixels {drawn_lo}..{drawn_hi}; the camera model puts it at {lo}..{hi}"


def test_every_shape_type_draws(browser, tmp_path):
    """Box, sphere, cylinder, capsule and an STL mesh on the pendulum: no console errors, and the cyan mesh
    (a tetrahedron, 0.1 m) appears next to the bob's projected position."""
    stl = tmp_path / "tetra.stl"
    stl.write_bytes(b"\0" * 80 + struct.pack("<I", 4) + b"".join(struct.pack("<12fH", 0, 0, 0, *tri.ravel(), 0) for tri in TETRA))
    text = (MODELS / "pendulum.yaml").read_text()
    text = text.replace("    mass: m_rod\n", "    mass: m_rod\n    shape: [{type: cylinder, radius: 0.01, length: L, at: [0, 0, -L/2]},"
                        " {type: capsule, radius: 0.02, length: 0.1, at: [0, 0, -0.2], color: orange, opacity: 0.5}]\n")
    text = text.replace("    mass: m_bob\n", "    mass: m_bob\n    shape: [{type: sphere, radius: r_bob, color: grey},"
                        " {type: box, size: [0.02, 0.02, 0.02], at: [0, 0, 0.1]},"
                        " {type: mesh, file: tetra.stl, scale: 0.1, color: '#00ffff', at: [0.03, 0, 0]}]\n")
    (tmp_path / "s.yaml").write_text(text)
    page = mbsfmu.animate(tmp_path / "s.yaml", tmp_path / "s.html", stop=0.2)
    data, _, _ = page_data(page)
    n_errors = len(browser.errors())
    img = browser.show(page, 0.0)
    assert browser.errors()[n_errors:] == []
    cyan = (img[..., 0] < 50) & (np.abs(img[..., 1] - img[..., 2]) < 30) & (img[..., 1] > 90)  # not the z axis' light blue
    rows, cols = np.nonzero(cyan)
    centroid = R_y(math.pi / 6) @ ([0, 0, -0.8] + np.array([0.03, 0, 0]) + 0.1 * TETRA.reshape(-1, 3).mean(axis=0))
    px = project(data["scene"]["camera"], centroid)
    assert len(rows) > 50 and np.linalg.norm([cols.mean(), rows.mean()] - px) < 4


@pytest.mark.slow
def test_native_fmu_motion_is_drawn(tmp_path):
    """An FMU run through fmpy, here with its scene given (--scene): the rod's drawn rotation follows the exact
    pendulum solution, and nothing of the viewer travels in the FMU."""
    import zipfile
    fmu = mbsfmu.build_fmu(MODELS / "pendulum.yaml", tmp_path, kind="native")
    assert not [n for n in zipfile.ZipFile(fmu).namelist() if "three" in n.lower() or "animation" in n.lower()]
    out = tmp_path / "fmu.html"
    assert main(["animate", str(fmu), "--scene", str(MODELS / "pendulum.yaml"), "--stop", "1.5", "-o", str(out)]) == 0
    _, t, F = page_data(out)
    assert abs(t[-1] - 1.5) < 1e-9
    angle = np.array([math.atan2(R[0, 2], R[0, 0]) for R in (quat_matrix(q) for q in F[:, 3:7])])
    assert np.max(np.abs(angle - pendulum_theta(t))) < 1e-5


# -- FMUs animated alone -------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def orphans(tmp_path_factory):
    """Both kinds built from the pendulum with a box on the bob, the scene file then deleted; and the page that
    animating the scene gave before."""
    tmp = tmp_path_factory.mktemp("orphans")
    scene = _bob_box_scene(tmp)
    fmus = {kind: mbsfmu.build_fmu(scene, tmp / kind, kind=kind) for kind in ("pythonfmu", "native")}
    page = mbsfmu.animate(scene, tmp / "scene.html", stop=1.0)
    scene.unlink()
    return fmus, page


def _same(a, b, path="data"):
    """Equal JSON data; numbers to 1e-9 (the FMU's run and the in-process run agree to ~1e-12)."""
    if isinstance(a, float) or isinstance(b, float):
        assert a == pytest.approx(b, rel=1e-9, abs=1e-12), path
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{k}]")
    else:
        assert a == b, path


@pytest.mark.parametrize("kind", ["pythonfmu", "native"])
def test_an_fmu_alone_animates_like_its_scene(orphans, kind, tmp_path):
    """`mbsfmu animate X.fmu` as docs/animation.md shows it, with the scene file gone: the page draws the
    same scene (bodies, links, shapes, sizes, camera) and the same motion as animating the scene did."""
    fmus, scene_page = orphans
    out = tmp_path / "fmu.html"
    assert main(["animate", str(fmus[kind]), "--stop", "1", "-o", str(out)]) == 0
    want, t0, F0 = page_data(scene_page)
    got, t, F = page_data(out)
    assert [s["type"] for b in got["scene"]["bodies"] for s in b["shapes"]] == ["box"]
    _same({k: got[k] for k in ("name", "description", "stride", "scene")},
          {k: want[k] for k in ("name", "description", "stride", "scene")})
    assert np.array_equal(t, t0) and np.allclose(F, F0, atol=1e-6)  # float32 frames


def _replaced(fmu, tmp_path, text=None, member="resources/mbsfmu_drawing.json"):
    """A copy of the FMU whose drawing description is `text` (None: removed)."""
    import zipfile
    out = tmp_path / fmu.name
    with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            if item.filename != member:
                zout.writestr(item, zin.read(item.filename))
        if text is not None:
            zout.writestr(member, text)
    return out


def test_foreign_drawing_descriptions_are_refused(orphans, tmp_path, capsys):
    """The description is foreign data: read bounded, parsed as JSON only, and used only if it compiles to the
    scene the FMU runs; anything else is one line that says to give --scene, within bounded time."""
    import zipfile
    fmu = orphans[0]["pythonfmu"]
    spec = json.loads(zipfile.ZipFile(fmu).read("resources/mbsfmu_drawing.json"))
    longer = json.loads(json.dumps(spec))
    next(p for p in longer["parameters"] if p["name"] == "L")["value"] = 0.9   # another pendulum
    huge_beam = json.loads(json.dumps(spec))
    huge_beam["bodies"][1]["elastic"] = {"beam": {"length": 1.0, "EI": [1.0, 1.0], "rhoA": 1.0, "elements": 10**6,
                                                  "modes": 2, "clamped": "start"}, "coordinates": ["q1", "q2"],
                                        "damping_ratio": 0.0, "dynamic_stiffening": True, "initial": {}, "initial_velocity": {}}
    def shaped(**change):  # shapes are drawing only: the scene file's shape rules check them
        s = json.loads(json.dumps(spec))
        s["bodies"][1]["shape"][0].update(change)
        return json.dumps(s)
    cases = {shaped(type="banana"): "unknown shape type", shaped(size=[1, -1, 1]): "positive",
             shaped(opacity=5): "opacity", shaped(color="url(javascript:x)"): "colour",
             shaped(type="mesh", file="../../etc/passwd", size=None): "outside the scene's folder",
             shaped(rotation={"axis": [0, 0, 1], "angle": 90}): "radians",
             None: "carries no drawing description", json.dumps(longer): "not the scene it runs",
             json.dumps(huge_beam): "at most 200", "\x80not json": "cannot read", "[" * 100_000: "cannot read",
             " " * (100 * 2**20): "larger than", json.dumps([spec]): "cannot read",
             json.dumps({**spec, "bodies": "x"}): "cannot read", "1" * 10_000: "cannot read"}
    for text, words in cases.items():
        bad = _replaced(fmu, tmp_path, text)
        t0 = time.process_time()
        assert main(["animate", str(bad), "-o", str(tmp_path / "x.html")]) == 1
        err = capsys.readouterr().err
        assert words in err and "--scene" in err and err.count("\n") == 1, err
        assert time.process_time() - t0 < 3, words
    assert not (tmp_path / "x.html").exists()
