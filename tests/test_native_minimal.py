"""Native FMUs of scenes that need few engine parts: each builds, links (its sources/ are what the FMI layer's
calls reach, engine.build.linked_sources), runs in the plain C host and equals the in-process run, and its
sources/ compile alone (the README's command line) into a library that gives the same numbers bit for bit.

The scenes leave out one part each: expressions (plain numbers, no parameters, no `t`), forces, outputs, inputs;
an elastic body with no parameters. The pendulum of plain numbers is also held against its closed-form energy.
"""
from __future__ import annotations

import subprocess
import zipfile

import numpy as np
import pytest

import mbsfmu
from mbsfmu.fmu import native
from test_fmu_native import _host_rows, _unpack, host  # noqa: F401  (host: the compiled C host fixture)

pytestmark = pytest.mark.skipif(native.compiler() is None, reason="no C compiler (cc, gcc, clang or $CC)")

PENDULUM = """mbsfmu: 1
name: {name}
bodies:
  bob:
    parent: world
    joint: {{type: revolute, axis: [0, 1, 0], coordinates: [theta], initial: {{theta: 0.5}}}}
    mass: 1.0
    center_of_mass: [0, 0, -1]
    inertia: {{xx: 0.01, yy: 0.01, zz: 0.01}}
{extra}"""
ELASTIC = """mbsfmu: 1
name: {name}
gravity: [0, 0, -9.81]
bodies:
  hub:
    parent: world
    joint: {{type: revolute, axis: [0, 0, 1], coordinates: [hub_angle], initial_velocity: {{hub_angle: 2.0}}}}
    mass: 2.0
    inertia: {{xx: 0.01, yy: 0.01, zz: 0.02}}
  beam:
    parent: hub
    joint: {{type: fixed, at: [0.05, 0, 0]}}
    elastic:
      beam: {{length: 1.0, EI: 20.0, rhoA: 0.6, elements: 4, modes: 2, clamped: start}}
{extra}"""
SCENES = {  # name: (text, engine parts it must leave out, parts it must carry)
    "plain_numbers": (PENDULUM.format(name="plain_numbers", extra=""), {"expr.c", "elastic.c"}, set()),
    "params_only": (PENDULUM.format(name="params_only", extra="parameters:\n  k: {value: 2.0}\n")
                    .replace("mass: 1.0", "mass: k/2"), {"elastic.c"}, {"expr.c"}),
    "time_force": (PENDULUM.format(name="time_force", extra="forces:\n  - {type: torque, body: bob, "
                                   "value: [0, 0.1*sin(t), 0]}\n"), {"elastic.c"}, {"expr.c"}),
    "input_no_output": (PENDULUM.format(name="input_no_output", extra="forces:\n  - {type: torque, body: bob, "
                                        "input: T}\n"), {"expr.c", "elastic.c"}, set()),
    "output_no_force": (PENDULUM.format(name="output_no_force", extra="outputs:\n  - {body: bob, point: [0, 0, -1]}\n"),
                        {"expr.c", "elastic.c"}, set()),
    "elastic_plain": (ELASTIC.format(name="elastic_plain", extra=""), {"expr.c"}, {"elastic.c"}),
    "elastic_output": (ELASTIC.format(name="elastic_output", extra="outputs:\n  - {body: beam, node: -1}\n"),
                       {"expr.c"}, {"elastic.c"}),
}
STEPS, H = 100, 0.01


@pytest.mark.parametrize("name", SCENES)
def test_minimal_scene_builds_runs_in_c_host_and_from_its_sources(name, host, tmp_path):  # noqa: F811
    text, left_out, carried = SCENES[name]
    scene_file = tmp_path / f"{name}.yaml"
    scene_file.write_text(text)
    fmu = mbsfmu.build_fmu(scene_file, tmp_path / "out", kind="native")
    c_files = {n[len("sources/"):] for n in zipfile.ZipFile(fmu).namelist()
               if n.startswith("sources/") and n.endswith(".c")}
    assert not c_files & left_out and carried <= c_files and {"fmi2.c", "model.c", "instance.c", "ode.c", "run.c", "tree.c"} <= c_files

    d, md, outs = _unpack(fmu, tmp_path / "x")
    args = [(d / "resources").as_uri(), md.guid, "-o", ",".join(map(str, outs)), "-n", str(STEPS), "-h", str(H), "-p"]
    shipped = d / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    fresh = tmp_path / "fresh.so"  # the README's command line: only the files of sources/, no -D flags
    src = d / "sources"
    subprocess.run([native.compiler(), "-O2", "-std=c99", "-shared", "-fPIC", "-fvisibility=hidden", f"-I{src}",
                    "-o", str(fresh), *map(str, sorted(src.glob("*.c"))), "-lm"], check=True)
    a, b = (subprocess.run([str(host), str(lib), *args], capture_output=True, text=True, timeout=60)
            for lib in (shipped, fresh))
    assert a.returncode == 0 and b.returncode == 0, (a.stdout[-1000:], a.stderr[-1000:], b.stderr[-1000:])
    rows = _host_rows(a.stdout)
    assert rows.shape[0] == STEPS + 1 and rows.tolist() == _host_rows(b.stdout).tolist()

    # the C host's outputs equal the in-process engine's run (y, yd columns by name)
    names = {v.valueReference: v.name for v in md.modelVariables}
    t, Y, YD = mbsfmu.simulate(mbsfmu.load(scene_file), stop=STEPS * H, step=H)
    ev = mbsfmu.compile(mbsfmu.load(scene_file))
    ref = {f"y.{c}": Y[:, k] for k, c in enumerate(ev.coordinates)}
    ref |= {f"yd.{c}": YD[:, k] for k, c in enumerate(ev.velocity_coordinates)}
    cols = [(j, names[vr]) for j, vr in enumerate(outs) if names[vr] in ref]
    assert len(cols) == Y.shape[1] + YD.shape[1]
    for j, n in cols:
        assert np.allclose(rows[:, 1 + j], ref[n], rtol=1e-12, atol=1e-12), n
    assert np.ptp(rows[:, 1:], axis=0).max() > 1e-3  # it moved

    if name in ("plain_numbers", "output_no_force"):  # conservative: E = ½ I_O θ̇² − m g l cos θ, I_O = 0.01 + 1
        th, thd = rows[:, 1 + [n for _, n in cols].index("y.theta")], rows[:, 1 + [n for _, n in cols].index("yd.theta")]
        E = 0.5 * 1.01 * thd ** 2 - 9.81 * np.cos(th)
        assert np.ptp(E) < 1e-6 * abs(E[0]), np.ptp(E)


@pytest.mark.parametrize("feats", [(), ("expr",), ("elastic",), ("expr", "elastic")])
def test_every_switch_combination_links_from_its_derived_sources(feats, tmp_path):
    """The class behind a scene of plain numbers failing to link: for each combination of the engine's
    switches, the files derived from the FMI layer's calls link with every symbol resolved (-z defs)."""
    from mbsfmu.engine import build
    _, _, defs = build.sources(feats)
    files = build.linked_sources([native.FMI_LAYER], defs)
    names = {f.name for f in files}
    assert ("expr.c" in names) == ("expr" in feats) and ("elastic.c" in names) == ("elastic" in feats)
    r = subprocess.run([native.compiler(), "-O0", "-std=c99", "-shared", "-fPIC", *defs, *build.include_flags(),
                        "-o", str(tmp_path / "x.so"), *map(str, files), "-lm",
                        "-Wl,-z,defs"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
