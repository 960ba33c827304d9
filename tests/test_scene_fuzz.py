"""Fuzzing the compiled-scene loader under ASan + UBSan (issue 22, item 7).

tests/c/scene_fuzz.c is compiled with the engine and `-fsanitize=address,undefined -fno-sanitize-recover=all` and
fed the compiled scenes of every shipped model (compiled as the FMU builders do: simulation.compiled). In one
process it mutates each scene in memory (every int field to edge values, bit flips, truncations, section rows
swapped, special doubles) and runs every mutant the way fmi2Instantiate and the first steps do. The reference is
the sanitizers themselves and the harness's own checks: no report, each mutant refused with a message or run (a
failing step with a message), bounded allocation per byte of the scene, no slow case.

A sanitizer report ends the harness; the driver records it and restarts after the case, so one run lists all.
Run as a script to print the figures: `PYTHONPATH=src python3 tests/test_scene_fuzz.py`.
"""
from __future__ import annotations

import os
import re
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
ENGINE = REPO / "src" / "mbsfmu" / "engine"
# float-cast-overflow on top (gcc's `undefined` leaves it out): a double from the file made into an index or count
SAN = ("-fsanitize=address,undefined,float-cast-overflow", "-fno-sanitize-recover=all")
# leaks are checked when the harness ends normally (memory a refused or freed scene keeps would show there)
ENV = {"ASAN_OPTIONS": "detect_leaks=1:allocator_may_return_null=0:abort_on_error=0",
       "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1"}
MAX_REPORTS = 30


def _cc():
    return os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")


def build(out: Path, feats=("expr", "elastic")) -> Path | None:
    """The harness with the engine parts `feats`, sanitized; None if the compiler lacks the sanitizers."""
    sys.path.insert(0, str(REPO / "src"))
    from mbsfmu.engine.build import include_flags, sources

    cc = _cc()
    if cc is None:
        return None
    probe = out.parent / "probe.c"
    probe.write_text("int main(void) { return 0; }\n")
    if subprocess.run([cc, *SAN, str(probe), "-o", str(out.parent / "probe")], capture_output=True).returncode:
        return None
    srcs, _, defs = sources(feats)
    cmd = [cc, "-O0", "-g", "-std=c99", *SAN, *defs, *include_flags(), "-o", str(out),
           str(REPO / "tests" / "c" / "scene_fuzz.c"), *map(str, srcs), "-lm"]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    return out


def shipped_scenes(folder: Path) -> list[Path]:
    """models/*.yaml compiled into folder/<name>.bin."""
    sys.path.insert(0, str(REPO / "src"))
    import mbsfmu
    from mbsfmu.simulation import compiled

    out = []
    for p in sorted((REPO / "models").glob("*.yaml")):
        blob, _, _ = compiled(mbsfmu.load(p).spec)
        dest = folder / f"{p.stem}.bin"
        dest.write_bytes(blob)
        out.append(dest)
    return out


def fuzz(harness: Path, scenes: list[Path], work: Path) -> dict:
    """Run every case; restart after each sanitizer report. Totals and the reports (case, first lines)."""
    progress = work / "progress"
    env = {**os.environ, **ENV, "FUZZ_PROGRESS": str(progress)}
    first, totals, reports, bad = 0, {}, [], []
    keys = ("cases", "refused", "ran", "failed", "abandoned", "maxms", "maxalloc")

    def add(values):
        for key, v in zip(keys, values):
            totals[key] = max(totals.get(key, 0), v) if key.startswith("max") else totals.get(key, 0) + v

    while len(reports) < MAX_REPORTS:
        res = subprocess.run([str(harness), str(first), *map(str, scenes)], capture_output=True, text=True, env=env,
                             timeout=600)
        bad += [line for line in res.stdout.splitlines() if line.startswith("FUZZ-BAD")]
        if first == 0:
            intact = dict(line.split(" ", 2)[1:] for line in res.stdout.splitlines() if line.startswith("FUZZ-INTACT"))
            totals["intact"] = {scenes[int(i)].stem: v.strip() for i, v in intact.items()}
        done = re.search(r"^FUZZ cases (\d+) refused (\d+) ran (\d+) failed (\d+) abandoned (\d+) maxms ([\d.]+) "
                         r"maxalloc (\d+)", res.stdout, re.M)
        if done:
            add(float(v) if "." in v else int(v) for v in done.groups())
            if "LeakSanitizer" in res.stderr:
                reports.append(("at exit", res.stderr[res.stderr.index("LeakSanitizer"):][:2000]))
            break
        case, refused, ran, failed, abandoned = struct.unpack("<5q", progress.read_bytes()[:40])
        add((case - first + 1, refused, ran, failed, abandoned))  # the reported case counts as a case
        lines = [ln for ln in res.stderr.splitlines() if "ERROR" in ln or "runtime error" in ln or "#" in ln]
        reports.append((case, "\n".join(lines[:8])))
        first = case + 1
    totals["reports"] = len(reports)
    return {"totals": totals, "reports": reports, "bad": bad}


# ---- the classes of defect one by one, in-process (the engine library): tables that disagree, counts that
# nothing in the file bounds. Each rule is the compiled-scene layout's (mbs_layout.h, elastic_tables.py).

def _compiled(name):
    sys.path.insert(0, str(REPO / "src"))
    import mbsfmu
    from mbsfmu.simulation import compiled

    blob, _, model = compiled(mbsfmu.load(REPO / "models" / f"{name}.yaml").spec)
    return blob, model


def _sections(blob):
    nsec = struct.unpack_from("<i", blob, 72)[0]
    return {sid: (row, kind, off, cnt) for row, (sid, kind, off, cnt) in
            ((76 + 24 * s, struct.unpack_from("<iiqq", blob, 76 + 24 * s)) for s in range(nsec))}


def _patch(blob, sid, index, value):
    """blob with int32 entry `index` of section `sid` set to value."""
    _, kind, off, _ = _sections(blob)[sid]
    assert kind == 0
    b = bytearray(blob)
    struct.pack_into("<i", b, off + 4 * index, value)
    return bytes(b)


def _refused(blob, *words):
    from mbsfmu.engine import EngineError, Instance

    with pytest.raises(EngineError) as e:
        Instance(blob)
    for w in words:
        assert w in str(e.value), str(e.value)
    return str(e.value)


def _c():
    from mbsfmu.engine import layout as c
    return c


def _header(blob, field, value):
    c = _c()
    return _patch(blob, c.S_HEADER, getattr(c, "H_" + field), value)


def _features(blob):
    c = _c()
    return struct.unpack_from("<i", blob, _sections(blob)[c.S_HEADER][2] + 4 * c.H_FEATURES)[0]


def test_elastic_references_pair_with_the_elastic_rows():
    """A body's elastic index names the elastic row that names that body (rows and elastic bodies pair one to
    one): an index on a rigid body, one past the table, and the elastic body's own index moved are refused."""
    c = _c()
    blob, model = _compiled("robot_arm_elastic")
    elastic = [i for i, b in enumerate(model.bodies) if b.elastic]
    rigid = [i for i, b in enumerate(model.bodies) if not b.elastic]
    assert len(elastic) == 1
    for body, value in [(rigid[0], 0), (rigid[-1], 0), (elastic[0], 1), (elastic[0], 2 ** 31 - 1), (elastic[0], -2)]:
        _refused(_patch(blob, c.S_BODY_I, body * c.IB + c.IB_ELASTIC, value), "elastic", f"body {body}")


def test_nodes_only_on_elastic_bodies():
    """A joint, a force end or an output sits at a node only of an elastic body: at a node of a rigid parent or
    rigid body, and anywhere in a scene without elastic bodies, it is refused."""
    c = _c()
    blob, model = _compiled("robot_arm_elastic")
    on_rigid_parent = [i for i, b in enumerate(model.bodies) if b.parent >= 0 and not model.bodies[b.parent].elastic]
    _refused(_patch(blob, c.S_BODY_I, on_rigid_parent[0] * c.IB + c.IB_NODE, 0), "node")
    rigid_out = [o for o, spec in enumerate(model.outputs) if not model.bodies[model.index[spec["body"]]].elastic]
    _refused(_patch(blob, c.S_OUT_I, 3 * rigid_out[0] + 1, 0), f"output {rigid_out[0]}")
    rigid_force = [n for n, fe in enumerate(model.bound_forces) if fe["type"] == "torque"
                   and not model.bodies[fe["body_index"]].elastic]
    _refused(_patch(blob, c.S_FORCE_I, rigid_force[0] * c.IF + c.IF_NODE_A, 0), "force")
    blob, model = _compiled("spring_damper")  # no elastic bodies at all
    _refused(_patch(blob, c.S_BODY_I, 1 * c.IB + c.IB_NODE, 0), "without elastic")
    _refused(_patch(blob, c.S_OUT_I, 1, 0), "output 0")
    spring = [n for n, fe in enumerate(model.bound_forces) if fe["type"] == "spring_damper"][0]
    for end in (c.IF_NODE_A, c.IF_NODE_B):
        _refused(_patch(blob, c.S_FORCE_I, spring * c.IF + end, 0), f"element {spring}")


def test_elastic_feature_bit_cleared_while_elastic_tables_are_used():
    """Without the elastic feature bit the engine does not check or run elastic tables: a scene that still names
    elastic data is refused (it used to reach elastic.c without its workspace)."""
    c = _c()
    blob, _ = _compiled("robot_arm_elastic")
    features = _features(blob)
    assert features & c.F_ELASTIC
    _refused(_header(blob, "FEATURES", features & ~c.F_ELASTIC), "without elastic bodies")
    _refused(_header(blob, "FEATURES", features | 4), "feature bits")


@pytest.mark.parametrize("name, body, change", [
    ("double_pendulum", 0, {"IB_NPOS": 0}), ("double_pendulum", 1, {"IB_NVEL": 6}),
    ("double_pendulum", 1, {"IB_JTYPE": 8}),      # revolute → free quaternion: 7/6 coordinates, it has 1/1
    ("free_body", 0, {"IB_NPOS": 6}), ("spinning_top", 0, {"IB_JTYPE": 1}),
])
def test_joint_type_and_its_coordinate_counts_agree(name, body, change):
    """A joint type moves a fixed number of coordinates (kinematics/joints.py); a body table that gives other
    counts would send the kinematics and the initial rotation through slots that are not coordinates."""
    c = _c()
    blob, _ = _compiled(name)
    for field, value in change.items():
        blob = _patch(blob, c.S_BODY_I, body * c.IB + getattr(c, field), value)
    _refused(blob, f"body {body}", "joint type")


def test_drive_slots_are_driven_coordinates():
    """Drive slots index the drives, and there are no more drives than driven coordinates."""
    c = _c()
    blob, model = _compiled("driven_crank")
    ib = struct.unpack_from(f"<{len(model.bodies) * c.IB}i", blob, _sections(blob)[c.S_BODY_I][2])
    body, k = next((i, k) for i in range(len(model.bodies)) for k in range(ib[i * c.IB + c.IB_NPOS])
                   if ib[i * c.IB + c.IB_POS + k] < 0)
    ndrv = len([d for b in model.bodies for d in b.drives])
    _refused(_patch(blob, c.S_BODY_I, body * c.IB + c.IB_DRV + k, ndrv), "drive")
    _refused(_header(blob, "NDRV", ndrv + 1), "drives")


@pytest.mark.parametrize("name, value", [("spinning_top", 1), ("robot_arm_6dof", 1), ("stress/gimbal_lock", 0)])
def test_cardan_count_is_the_body_tables(name, value):
    """The header's count of Cardan joints (it switches the gimbal-lock checks on) is the body table's."""
    blob, model = _compiled(name)
    assert sum(b.kind in ("spherical", "free") and b.param == "cardan" for b in model.bodies) != value
    _refused(_header(blob, "NCARDAN", value), "Cardan")


@pytest.mark.parametrize("value", [2, 2 ** 31 - 1])
def test_the_evaluation_path_is_one_of_two(value):
    """H_DENSE names the dense (1) or the recursive (0) path; anything else is refused at load."""
    blob, _ = _compiled("cart_pole")
    _refused(_header(blob, "DENSE", value), "evaluation path")


@pytest.mark.parametrize("field, value", [("NDRV", 30_000_000), ("NVEC", 30_000_000), ("NINPUT", 30_000_000),
                                          ("NDRV", 2 ** 31 - 1), ("NQUAT", 2 ** 31 - 1), ("NOUT", 2 ** 31 - 1),
                                          ("NB", 2 ** 31 - 1), ("NVEL", 2 ** 31 - 1), ("NVARS", 2 ** 31 - 1)])
def test_counts_are_bounded_by_the_bytes_present(field, value):
    """A count nothing in a 2.5 kB file backs (3e7 drives made the host allocate 700 MB) is refused at load:
    drives by the driven coordinates, vector slots by the force elements, the rest by their sections or the
    length of the numbers they lay out."""
    blob, _ = _compiled("cart_pole")
    assert len(blob) < 4096
    _refused(_header(blob, field, value), "corrupt")


@pytest.mark.parametrize("name", ["flexible_pendulum", "double_pendulum"])
def test_workspace_limit_of_compile_py_holds_at_load(name):
    """A compiled scene whose tables do hold 20,000 more coordinates (consistent layout, names and coordinate
    lists; 400 kB): on the dense path its header names (H_DENSE, both scenes are small) it would need 3 GiB of
    dense workspace, and the loader refuses it with its size; on the recursive path (linear workspace) it is refused
    because no joint moves the extra coordinates."""
    c = _c()
    blob, model = _compiled(name)
    sec = _sections(blob)
    fmt = {0: "i", 1: "d", 2: "B"}
    arrays = {sid: list(struct.unpack_from(f"<{n}{fmt[kind]}", blob, off)) for sid, (_, kind, off, n) in sec.items()}
    H, h = arrays[c.S_HEADER], {e[0][2:]: c.CONSTANTS[e[0]] for e in c.LISTS["MBS_HEADER"]}
    np_, nv, extra = H[h["NPOS"]], H[h["NVEL"]], 20000
    D, x0 = arrays[c.S_D], H[h["D_X0"]]
    nom = x0 + np_ + nv   # the states' nominals follow x0 (H_D_NOMINAL)
    arrays[c.S_D] = (D[:x0 + np_] + [0.0] * extra + D[x0 + np_:nom] + [0.0] * extra
                     + D[nom:nom + np_] + [1.0] * extra + D[nom + np_:nom + np_ + nv] + [1.0] * extra + D[nom + np_ + nv:])
    plain = arrays[c.S_PLAIN]
    k = H[h["NPLAIN"]]
    arrays[c.S_PLAIN] = plain[:k] + list(range(np_, np_ + extra)) + plain[k:] + list(range(nv, nv + extra))
    names = bytes(arrays[c.S_NAMES]).split(b"\0")[:-1]
    names = names[:np_] + [f"x{i}".encode() for i in range(extra)] + names[np_:]
    arrays[c.S_NAMES] = list(b"".join(n + b"\0" for n in names))
    for key in ("NPOS", "NVEL", "NPLAIN"):
        H[h[key]] += extra
    H[h["D_NOMINAL"]] += 2 * extra
    for key in ("D_OUT", "D_INTEG", "ND"):
        H[h[key]] += 4 * extra
    from mbsfmu.compiler.scene_file import _pack
    parts = [(sid, np.array(arrays[sid], dtype={0: np.int32, 1: float, 2: np.uint8}[kind]))
             for sid, (_, kind, _, _) in sorted(sec.items())]
    big = _pack(parts, blob[8:72].split(b"\0")[0].decode())
    assert H[h["DENSE"]] == 1
    _refused(big, "scene too large", f"{nv + extra} velocity coordinates", "GiB")
    H[h["DENSE"]] = 0
    parts = [(sid, np.array(arrays[sid], dtype={0: np.int32, 1: float, 2: np.uint8}[kind]))
             for sid, (_, kind, _, _) in sorted(sec.items())]
    _refused(_pack(parts, "g"), "corrupt body table", f"velocity coordinate {nv} is not moved by exactly one joint")
    H[h["NVEL"]] -= 1  # and the same file with one count off is corrupt, not large
    parts = [(sid, np.array(arrays[sid], dtype={0: np.int32, 1: float, 2: np.uint8}[kind]))
             for sid, (_, kind, _, _) in sorted(sec.items())]
    _refused(_pack(parts, "g"), "corrupt")


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    return shipped_scenes(tmp_path_factory.mktemp("scenes"))


# the in-process engine (all parts) and a rigid scene's native FMU (no elastic.c: elastic scenes are refused). A
# native FMU without expressions runs no shipped scene (each has some), so it would only refuse.
@pytest.mark.parametrize("feats", [("expr", "elastic"), ("expr",)], ids=["full", "rigid"])
def test_mutated_compiled_scenes_are_refused_or_run_without_sanitizer_reports(scenes, tmp_path, feats):
    harness = build(tmp_path / "scene_fuzz", feats)
    if harness is None:
        pytest.skip("the C compiler lacks -fsanitize=address,undefined")
    r = fuzz(harness, scenes, tmp_path)
    t = r["totals"]
    detail = "\n\n".join(f"case {c}:\n{text}" for c, text in r["reports"][:5]) + "\n" + "\n".join(r["bad"][:20])
    assert t["reports"] == 0 and not r["bad"], f"{t}\n{detail}"
    assert t["cases"] >= 10000 and t["refused"] > 0 and t["ran"] > 0, t
    for path in scenes:  # the intact scenes run; a rigid engine refuses the elastic ones, saying why
        elastic = _features(path.read_bytes()) & _c().F_ELASTIC
        want = "refused the scene has elastic bodies but this engine was built without them" \
            if elastic and "elastic" not in feats else "ran"
        assert t["intact"][path.stem].startswith(want), (path.stem, t["intact"][path.stem])


if __name__ == "__main__":  # the figures for the issue
    import tempfile
    import time

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        sc = shipped_scenes(d)
        for feats in (("expr", "elastic"), ("expr",)):
            h = build(d / f"fuzz_{'_'.join(feats)}", feats)
            t0 = time.perf_counter()
            r = fuzz(h, sc, d)
            print("+".join(feats) or "plain", r["totals"], f"{time.perf_counter() - t0:.1f} s")
            for c, text in r["reports"]:
                print(f"--- case {c}\n{text}")
            print("\n".join(r["bad"][:40]))
