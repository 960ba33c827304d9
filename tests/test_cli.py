"""Command line: subprocess runs (one-line errors, exit 1, no traceback), simulate with an input
CSV and a plot, crosscheck layout accepted by fmpy's cross-check validation, fmutool -check."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "models" / "double_pendulum.yaml"


def cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "mbsfmu.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=300, cwd=cwd)


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli")
    r = cli("build", MODEL, "-o", out)
    assert r.returncode == 0, r.stderr
    return out / "double_pendulum.fmu"


def test_help_has_examples():
    r = cli("--help")
    assert r.returncode == 0 and "examples:" in r.stdout and "crosscheck" in r.stdout


@pytest.mark.parametrize("args", [
    ("build", "nonexistent.yaml"),
    ("info", "nonexistent.fmu"),
    ("validate", "nonexistent.fmu"),
    ("simulate", "nonexistent.fmu"),
    ("check", "BROKEN"),
])
def test_errors_are_one_line(args, tmp_path):
    if args[-1] == "BROKEN":
        bad = tmp_path / "broken.yaml"
        bad.write_text("mbsfmu: 1\nname: broken\nbodies:\n  a: {parent: nowhere}\n")
        args = args[:-1] + (bad,)
    r = cli(*args, cwd=tmp_path)
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_build_progress_for_several_scenes(tmp_path):
    r = cli("build", REPO / "models" / "pendulum.yaml", MODEL, "-o", tmp_path)
    assert r.returncode == 0, r.stderr
    assert "[1/2]" in r.stdout and "[2/2]" in r.stdout
    assert (tmp_path / "double_pendulum.fmu").exists()


def test_simulate_with_input_and_plot(fmu, tmp_path):
    inp = tmp_path / "u.csv"
    inp.write_text("time,q.phi1\n0,0\n0.1,0.5\n0.2,0.5\n")
    png = tmp_path / "out.png"
    csv = tmp_path / "res.csv"
    r = cli("simulate", fmu, "--input", inp, "--stop", 0.2, "--plot", png, "--csv", csv)
    assert r.returncode == 0, r.stderr
    assert png.stat().st_size > 1000
    header = csv.read_text().splitlines()[0].split(",")
    assert header[0] == "time" and "y.phi1" in header and "yd.phi2" in header
    bad = tmp_path / "bad.csv"
    bad.write_text("time,nope\n0,1\n")
    r = cli("simulate", fmu, "--input", bad, "--stop", 0.1)
    assert r.returncode == 1 and "nope" in r.stderr and "Traceback" not in r.stderr


def test_info_and_validate(fmu):
    r = cli("info", fmu)
    assert r.returncode == 0 and "outputs" in r.stdout
    r = cli("validate", fmu)
    assert r.returncode == 0 and "valid" in r.stdout


def test_crosscheck_layout_validates(tmp_path):
    from fmpy.cross_check.validate_vendor_repo import validate_test_fmu
    d = tmp_path / "fmus" / "2.0" / "cs" / "linux64" / "mbsfmu" / "0.1.0" / "double_pendulum"
    r = cli("crosscheck", MODEL, "--out", d)
    assert r.returncode == 0, r.stderr
    for suffix in (".fmu", "_ref.csv", "_ref.opt", "_in.csv"):
        assert (d / f"double_pendulum{suffix}").is_file(), suffix
    assert validate_test_fmu(str(d)) == []


def test_fmutool_check(fmu):
    exe = shutil.which("fmutool")
    if exe is None:
        pytest.skip("fmu-manipulation-toolbox not installed")
    r = subprocess.run([exe, "-input", str(fmu), "-check"], capture_output=True, text=True, timeout=120)
    text = r.stdout + r.stderr
    assert r.returncode == 0, text
    assert "compliant with FMI-2.0" in text and "No semantic error" in text
    assert "ERROR" not in text.upper().replace("NO SEMANTIC ERROR", "")


# ---- a newcomer's first hour (issue 13): no tracebacks, readable output ----------------------------------
PENDULUM = REPO / "models" / "pendulum.yaml"


def _one_line_failure(r):
    assert r.returncode != 0, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


@pytest.mark.parametrize("args", [
    ("simulate", PENDULUM, "--stop", "-1"),
    ("simulate", PENDULUM, "--step", "0"),
    ("simulate", PENDULUM, "--stop", "abc"),
    ("simulate", PENDULUM, "--stop", "nan"),
    ("simulate", PENDULUM, "--stop", "2", "--step", "3"),
    ("simulate", PENDULUM, "--stop", "1e9", "--step", "1e-6"),
    ("simulate", PENDULUM, "--stop", "1", "--signals", "nope.*"),
    ("simulate", PENDULUM, "--stop", "1", "--method", "euler"),
    ("check", "FMU"),
    ("build", "FMU"),
    ("info", PENDULUM),
    ("check", "BINARY"),
    ("animate", PENDULUM, "--stop", "-1"),
    (),
    ("nonsense",),
    ("simulate",),
])
def test_bad_invocations_fail_in_one_line(args, tmp_path, monkeypatch, capsys):
    """In-process for speed: anything escaping main() other than argparse's exit would fail the test
    (`test_errors_are_one_line` covers the subprocess path)."""
    import zipfile
    from mbsfmu.cli import main
    fake = {"FMU": tmp_path / "x.fmu", "BINARY": tmp_path / "x.yaml"}
    with zipfile.ZipFile(fake["FMU"], "w") as z:
        z.writestr("modelDescription.xml", "<fmiModelDescription/>")
    fake["BINARY"].write_bytes(bytes(range(256)) * 4)
    monkeypatch.chdir(tmp_path)
    try:
        code = main([str(fake.get(a, a)) for a in args])
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    _one_line_failure(subprocess.CompletedProcess(args, code, out, err))


def test_closed_pipe_ends_quietly(tmp_path):
    """`mbsfmu simulate … | head`: the reader is gone before anything is written → exit 141, stderr empty."""
    p = subprocess.Popen([sys.executable, "-m", "mbsfmu.cli", "simulate", str(PENDULUM), "--stop", "1"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path)
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(timeout=300) == 141 and err == "", err


def test_every_option_has_help():
    import argparse
    from mbsfmu.cli import parser
    top = parser()
    sub = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))
    assert {"build", "check", "simulate", "info", "validate", "bench", "stress"} <= set(sub.choices)
    missing = [f"{name} {a.dest}" for name, p in sub.choices.items() for a in p._actions if not a.help]
    assert missing == []
    r = cli("simulate", "--help")
    assert r.returncode == 0 and "--stop" in r.stdout and "end time" in r.stdout and "--signals" in r.stdout


def test_table_says_which_rows_it_shows(tmp_path):
    r = cli("simulate", PENDULUM, "--stop", "2", "--step", "0.01", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "# showing 21 of 201 rows, one every 10 (all rows: --csv FILE)"
    assert [float(ln.split(",")[0]) for ln in lines[2:]] == pytest.approx([0.1 * k for k in range(21)])


def test_scene_run_shows_the_output_points_like_the_fmu(fmu, tmp_path):
    """The same outputs (y, yd and the `outputs:` points) for a scene and its FMU; the bob of the pendulum
    scene sits at L·(−sin θ, 0, −cos θ) (independent check of the point columns)."""
    scene_csv, fmu_csv = tmp_path / "scene.csv", tmp_path / "fmu.csv"
    r = cli("simulate", PENDULUM, "--stop", "1", "--csv", scene_csv)
    assert r.returncode == 0, r.stderr
    import numpy as np
    data = np.genfromtxt(scene_csv, delimiter=",", names=True, deletechars="")
    L = 0.8
    assert np.allclose(data["bob.r.x"], -L * np.sin(data["y.theta"]), atol=1e-12)
    assert np.allclose(data["bob.r.z"], -L * np.cos(data["y.theta"]), atol=1e-12)
    assert np.allclose(data["bob.v.x"], -L * np.cos(data["y.theta"]) * data["yd.theta"], atol=1e-12)
    pend_fmu = tmp_path / "pendulum.fmu"
    assert cli("build", PENDULUM, "-o", tmp_path).returncode == 0
    r = cli("simulate", pend_fmu, "--stop", "1", "--csv", fmu_csv)
    assert r.returncode == 0, r.stderr
    assert fmu_csv.read_text().splitlines()[0] == scene_csv.read_text().splitlines()[0]
    other = np.genfromtxt(fmu_csv, delimiter=",", names=True, deletechars="")
    assert np.allclose(other["y.theta"], data["y.theta"], atol=1e-9)


def test_signals_choose_columns_and_plot_has_a_panel_per_unit(tmp_path):
    from mbsfmu.plot import panels, styles
    r = cli("simulate", REPO / "models" / "robot_arm_6dof.yaml", "--stop", "0.2", "--signals", "y.*,*.r.z",
            "--csv", tmp_path / "r.csv", "--plot", tmp_path / "r.png")
    assert r.returncode == 0, r.stderr
    header = (tmp_path / "r.csv").read_text().splitlines()[0].split(",")
    assert header[0] == "time" and all(h.startswith("y.") or h.endswith(".r.z") for h in header[1:])
    assert (tmp_path / "r.png").stat().st_size > 10_000
    assert panels(["rad", "rad/s", "rad", "m", None, "1"]) == {"rad": [0, 2], "rad/s": [1], "m": [3], "1": [4, 5]}
    assert len({(s["color"], s["linestyle"]) for s in styles()}) == 40  # distinct well past 10 curves


def test_input_from_a_scene_leaves_no_temporary_files(tmp_path):
    inp = tmp_path / "u.csv"
    inp.write_text("time,q.theta\n0,0\n0.1,0.5\n")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    r = subprocess.run([sys.executable, "-m", "mbsfmu.cli", "simulate", str(PENDULUM), "--input", str(inp),
                        "--stop", "0.2"], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                       env={**__import__("os").environ, "TMPDIR": str(tmp)})
    assert r.returncode == 0, r.stderr
    assert list(tmp.glob("mbsfmu_sim_*")) == []


def test_stress_without_out_writes_a_fresh_folder(tmp_path):
    r = cli("stress", "--quick", "--cases", "nan_input", "--methods", "rk4", "--no-progress", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    made = [p for p in tmp_path.iterdir() if p.name.startswith("stress-")]
    assert len(made) == 1 and (made[0] / "stress.md").is_file()
    assert f"output folder: {made[0].name}/" in r.stdout


# -- what a new user hit -------------------------------------------------------------------------------------

def test_version_and_python_dash_m():
    """`mbsfmu --version` and `python -m mbsfmu` (same command) print the installed distribution's version."""
    from importlib.metadata import version
    r = subprocess.run([sys.executable, "-m", "mbsfmu", "--version"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == f"mbsfmu {version('mbsfmu')}", r
    r = subprocess.run([sys.executable, "-m", "mbsfmu", "check", str(PENDULUM)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.startswith("pendulum: 2 bodies"), r


def _commands():
    """Every command with arguments that reach its option parsing, and one of its long options."""
    from mbsfmu.cli import parser
    top = parser()
    for name, p in top.commands.items():
        if name in ("bench", "stress"):
            continue
        positional = [str(PENDULUM)] * sum(1 for a in p._actions if not a.option_strings and a.nargs != 0)
        options = sorted(o for o in p._option_string_actions if o.startswith("--") and o != "--help")
        yield name, positional, options
    yield "bench", [str(PENDULUM)], ["--quick", "--methods", "--out"]
    yield "stress", [], ["--quick", "--cases", "--methods"]


@pytest.mark.parametrize("name, positional, options", list(_commands()), ids=lambda x: x if isinstance(x, str) else "")
def test_a_mistyped_option_points_to_the_commands_help(name, positional, options, capsys, tmp_path, monkeypatch):
    """Every command, every long option with one letter dropped (--stp): one line naming the command's own
    help and the option meant."""
    from mbsfmu.cli import main
    monkeypatch.chdir(tmp_path)  # bench and stress name a fresh folder here (not created on a usage error)
    for option in options:
        typo = option[:3] + option[4:]
        if any(o.startswith(typo) for o in options):  # argparse takes unambiguous prefixes as they are
            continue
        with pytest.raises(SystemExit) as e:
            main([name, *positional, typo])
        err = capsys.readouterr().err
        assert e.value.code == 2 and err.count("\n") == 1, err
        assert err.startswith(f"mbsfmu {name}: error: unrecognized arguments: {typo}") and f"did you mean {option}?" in err, err
        assert err.rstrip().endswith(f"(see mbsfmu {name} --help)"), err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("args, meant", [(["--verison"], "--version"), (["simulat", "x"], "simulate"),
                                         (["build", "--kind", "natve", "x"], "native")])
def test_mistyped_commands_and_choices_get_a_suggestion(args, meant, capsys):
    from mbsfmu.cli import main
    with pytest.raises(SystemExit) as e:
        main(args)
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and f"did you mean {meant}?" in err, err


@pytest.mark.parametrize("cell, words", [("abc", "'abc' is not a finite number"), ("", "an empty cell"),
                                         ("nan", "'nan' is not a finite number"), ("1e999", "'1e999'")])
def test_input_csv_cells_must_be_numbers(cell, words, fmu, tmp_path, capsys):
    """A cell that is not a number stops `simulate --input` (scene and FMU) and `animate --input/--result`
    with its row and column: it never becomes NaN, and nothing is written."""
    from mbsfmu.cli import main
    bad = tmp_path / "in.csv"
    bad.write_text(f"time,q.phi1\n0,1\n0.5,{cell}\n1,0\n")
    out = tmp_path / "out.csv"
    for args in (["simulate", str(fmu), "--input", str(bad), "--csv", str(out)],
                 ["simulate", str(MODEL), "--input", str(bad), "--csv", str(out)],
                 ["animate", str(MODEL), "--input", str(bad), "-o", str(tmp_path / "a.html")]):
        assert main(args) == 1
        err = capsys.readouterr().err
        assert f"{bad}:3: column 'q.phi1'" in err and words in err and err.count("\n") == 1, err
    result = tmp_path / "r.csv"
    result.write_text(f"time,y.phi1,y.phi2\n0,0,0\n0.1,{cell},0\n")
    assert main(["animate", str(MODEL), "--result", str(result), "-o", str(tmp_path / "a.html")]) == 1
    assert f"{result}:3: column 'y.phi1'" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.csv", "r.csv"]


def test_missing_mingw_is_one_plain_note(tmp_path, monkeypatch, capsys):
    """Building a native FMU without the Windows cross compiler: a note of one line, no Python warning
    text or source line."""
    import shutil as sh
    from mbsfmu.cli import main
    from mbsfmu.fmu import native
    which = sh.which
    monkeypatch.setattr(native.shutil, "which", lambda name, *a, **k: None if name == native.MINGW else which(name, *a, **k))
    assert main(["build", "--kind", "native", str(PENDULUM), "-o", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("note: native FMU pendulum: no binaries/win64"), err
    assert "Warning" not in err and ".py:" not in err


def test_info_escapes_what_the_fmu_says(fmu, tmp_path, capsys):
    """`mbsfmu info` quotes a foreign file (the modelDescription): bidi overrides and C1 controls, which XML
    allows, reach the terminal as escapes."""
    import zipfile
    from mbsfmu.cli import main
    hostile = tmp_path / "h.fmu"
    with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(hostile, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = re.sub(rb'description="[^"]*"', 'description="evil\u202e\u009b2J"'.encode(), data, count=2)
            zout.writestr(item, data)
    assert main(["info", str(hostile)]) == 0
    out = capsys.readouterr().out
    assert "evil\\u202e\\x9b2J" in out and all(line.isprintable() for line in out.splitlines()), out


@pytest.mark.parametrize("args, words", [(["--input", "q.theta=abc", "--vary", "L=1,2"], "--input q.theta=abc: 'abc'"),
                                         (["--vary", "L=nan,1"], "--vary L=nan,1: 'nan'"),
                                         (["--vary", "L=0.5:inf:3"], "--vary L=0.5:inf:3: 'inf'")])
def test_sweep_numbers_must_be_finite(args, words, capsys):
    """The sweep's numbers from the command line: never a NaN case, one line naming the option."""
    from mbsfmu.cli import main
    assert main(["sweep", str(PENDULUM), *args, "--stop", "0.1"]) == 1
    err = capsys.readouterr().err
    assert err == f"error: {words} is not a finite number\n", err


# ---- issue 34 --------------------------------------------------------------------------------------------
SLIDER = """mbsfmu: 1
name: slider
gravity: [0, 0, 0]
bodies:
  cart:
    parent: world
    joint: {type: prismatic, axis: [1, 0, 0], coordinates: [x]}
    mass: 2.0
    inertia: {xx: 0.01, yy: 0.01, zz: 0.01}
integrator: {method: dopri5, rtol: 1e-10, atol: 1e-12}
experiment: {start: 0, stop: 3, step: 0.1}
"""


def _held_force_x(t, rows, m=2.0):
    """x(t) of a free mass m from rest under a force held from each row's time to the next (piecewise quadratic)."""
    import numpy as np
    out = []
    for T in t:
        x = v = 0.0
        for k, (tk, F) in enumerate(rows):
            end = min(T, rows[k + 1][0]) if k + 1 < len(rows) else T
            h = max(0.0, end - tk)
            x, v = x + v * h + F / m * h * h / 2, v + F / m * h
        out.append(x)
    return np.array(out)


def test_input_table_is_held_everywhere(fmu, tmp_path, capsys):
    """Item 7: an input CSV means one thing for the CLI (scene and FMU) and mbsfmu.simulate: each row's value
    held until the next row's time (a row between communication points included); --interpolate linear is
    the other reading. Against the free mass's closed form, and the CLI against the Python API."""
    import numpy as np
    import mbsfmu
    from mbsfmu.cli import main
    scene = tmp_path / "slider.yaml"
    scene.write_text(SLIDER)
    for rows in ([(0, 0), (1, 5), (2, 0)], [(0, 0), (0.55, 4), (1.23, -2), (1.23, 3)]):
        table = tmp_path / "u.csv"
        table.write_text("time,q.x\n" + "".join(f"{a},{b}\n" for a, b in rows))
        t, Y, _ = mbsfmu.simulate(str(scene), inputs=str(table))
        assert np.abs(Y[:, 0] - _held_force_x(t, rows)).max() < 1e-12
        out = tmp_path / "r.csv"
        assert main(["simulate", str(scene), "--input", str(table), "--csv", str(out)]) == 0
        assert np.abs(np.loadtxt(out, delimiter=",", skiprows=1)[:, 1] - Y[:, 0]).max() < 1e-12
    # linear: interpolated at each communication point t_k and held to t_k+1 (rk4 is exact on each step)
    t, Y, _ = mbsfmu.simulate(str(scene), inputs=str(table), inputs_interpolation="linear", method="rk4")
    F = np.interp(t, [r[0] for r in rows[:3]] + [1.23], [0, 4, -2, 3])
    rows_lin = list(zip(t, F))
    assert np.abs(Y[:, 0] - _held_force_x(t, rows_lin)).max() < 1e-12
    # the FMU through fmpy: the table on the double pendulum, CLI against the Python API
    table.write_text("time,q.phi1\n0,0\n1,5\n2,0\n")
    capsys.readouterr()
    assert main(["simulate", str(fmu), "--input", str(table), "--stop", "3", "--csv", str(out)]) == 0
    got = np.loadtxt(out, delimiter=",", skiprows=1)
    t, Y, YD = mbsfmu.simulate(str(MODEL), stop=3, inputs=str(table))
    assert got.shape[0] == len(t) and np.allclose(got[:, 0], t)
    assert np.abs(got[:, 1:3] - Y).max() < 1e-8
    assert main(["simulate", str(fmu), "--input", str(table), "--stop", "3", "--csv", str(out),
                 "--interpolate", "linear"]) == 0
    assert np.abs(np.loadtxt(out, delimiter=",", skiprows=1)[-1, 1:3] - Y[-1]).max() > 0.01  # the other reading


def test_fmpy_notes_stay_off_the_table(fmu, tmp_path):
    """Item 17: an FMU input missing from the CSV makes fmpy print a warning: on stderr, stdout stays a table."""
    import numpy as np
    table = tmp_path / "u.csv"
    table.write_text("time,q.phi1\n0,0\n0.5,1\n")  # no q.phi2
    r = cli("simulate", fmu, "--input", table, "--stop", "1")
    assert r.returncode == 0 and 'missing input for variable "q.phi2"' in r.stderr, r.stderr
    lines = [ln for ln in r.stdout.splitlines() if not ln.startswith("#")]
    assert lines[0] == "time,y.phi1,y.phi2,yd.phi1,yd.phi2"
    rows = np.array([[float(c) for c in ln.split(",")] for ln in lines[1:]])
    assert rows.shape == (21, 5) and rows[-1, 0] == 1.0


def test_help_check_and_info_say_what_is_there(tmp_path, capsys):
    """Item 20: the top line names FMI 3 and model exchange; build/check/simulate take URDFs too; bench and
    stress show --out as optional; check lists outputs and parameters; info prints no '= None'; modal
    coordinates are in metres (the generators scale each mode's largest node translation to 1, as
    docs/scene-format.md says) and stresses in Pa, each plotted under its quantity."""
    from mbsfmu.cli import main, parser
    from mbsfmu.plot import QUANTITY
    top = parser()
    assert "FMI 2.0 and 3.0" in top.description and "model exchange" in top.description
    for name in ("build", "check", "simulate"):
        assert ".urdf" in top.commands[name].format_help(), name
    for name in ("bench", "stress"):
        with pytest.raises(SystemExit):
            main([name, "--help"])
        usage = capsys.readouterr().out
        assert "[--out OUT]" in usage and "default: a fresh" in usage, usage
    assert main(["check", str(REPO / "models" / "fe_stress.yaml")]) == 0
    out = capsys.readouterr().out
    assert "  outputs: y.theta, y.link.q1" in out and "vm.link.gauge_top" in out and "  parameters: none" in out
    assert main(["check", str(PENDULUM)]) == 0
    assert "  parameters: L = 0.8, m_rod = 0.3, m_bob = 1, r_bob = 0.031\n" in capsys.readouterr().out
    fmu = __import__("mbsfmu").build_fmu(REPO / "models" / "fe_stress.yaml", tmp_path)
    assert main(["info", str(fmu)]) == 0
    out = capsys.readouterr().out
    assert "None" not in out and "    y.link.q1 [m]  " in out and "    yd.link.q1 [m/s]  " in out, out
    assert "    vm.link.gauge_top [Pa]  " in out and "    q.link.q1 [N] = 0" in out
    assert QUANTITY["Pa"] == "von Mises stress" and QUANTITY["m"] == "position"


def test_slow_steps_say_what_they_do(tmp_path, monkeypatch, capsys):
    """Item 21: a native build says on stderr (a terminal) that it compiles before it does; a warning of several
    lines (Dask's note that a port is taken) is one note line; the sweep's bar shows no time left until 5 % of
    the cases are done, then tqdm's estimate."""
    import io
    import warnings
    import mbsfmu
    from mbsfmu.cli import main
    from mbsfmu.sweep.dispatch import _bar
    said = []
    monkeypatch.setattr(mbsfmu, "build_fmu", lambda scene, out, **k: said.append(capsys.readouterr().err) or "x.fmu")
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert main(["build", "--kind", "native", str(PENDULUM), "-o", str(tmp_path)]) == 0
    assert said == [f"building {PENDULUM}: compiling the engine's C sources (10–60 s) …\n"]
    monkeypatch.setattr(mbsfmu, "build_fmu", lambda *a, **k: warnings.warn("Port 8787 is in use.\nPerhaps ...\nHosting on 4"))
    main(["build", str(PENDULUM), "-o", str(tmp_path)])
    assert capsys.readouterr().err == "note: Port 8787 is in use. Perhaps ... Hosting on 4\n"
    shown = io.StringIO()
    monkeypatch.setattr(sys, "stderr", shown)
    with _bar(100, True) as bar:
        bar.update(1)
        bar.bar.refresh()
        first = shown.getvalue().rsplit("\r", 1)[-1]
        bar.update(4)
        bar.bar.refresh()
        later = shown.getvalue().rsplit("\r", 1)[-1]
    assert "time left: estimating" in first and "<" not in first, first
    assert "time left" not in later and "<" in later, later  # tqdm's [elapsed<remaining, rate]
