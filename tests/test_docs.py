"""docs/ is the contract: every example scene builds a valid FMU, the examples cover every joint and force type,
two of them follow their closed-form motion (so the documented axis and coordinate conventions are right), the
documented commands parse, the Python pages run, links resolve. A fresh virtual environment following the README
is slow: run it with MBSFMU_SLOW=1."""
from __future__ import annotations

import math
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.cli import parse

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
EXAMPLES = sorted((DOCS / "examples").glob("*.yaml"))
PAGES = [REPO / "README.md"] + sorted(DOCS.glob("*.md"))
OWN_PAGES = [REPO / "README.md"] + [DOCS / n for n in ("README.md", "scene-format.md", "fmu.md", "python-api.md",
                                                      "integrators.md", "cli.md")]
PLANNED = {"animation.md", "sweeps.md"}  # written by the animation and sweep work (issues 15, 14)


def blocks(page, lang):
    return re.findall(rf"```{lang}\n(.*?)```", page.read_text(encoding="utf-8"), re.S)


def test_examples_cover_every_joint_and_force_type():
    from mbsfmu.scene.load import FORCE_TYPES, JOINT_TYPES
    joints, forces, params, elastic, drives, outputs = set(), set(), set(), False, False, False
    for f in EXAMPLES:
        spec = mbsfmu.load(f).spec
        for b in spec["bodies"]:
            joints.add(b["joint"]["type"])
            params.add(b["joint"].get("parameterization"))
            elastic |= bool(b["elastic"])
            drives |= bool(b["joint"]["drive"])
        forces |= {g["type"] for g in spec["forces"]}
        outputs |= bool(spec["outputs"])
    assert joints == set(JOINT_TYPES)
    assert forces == set(FORCE_TYPES)
    assert {"quaternion", "cardan"} <= params and elastic and drives and outputs
    text = (DOCS / "scene-format.md").read_text(encoding="utf-8")
    for f in EXAMPLES:
        assert f"examples/{f.name}" in text, f"{f.name} is not linked from scene-format.md"


def test_joint_table_of_the_docs_is_the_joint_table():
    """scene-format.md's joint table states, for every joint type of the table (kinematics/joints.py), its dof,
    every default coordinate name of each parameterization and the fields it takes."""
    from mbsfmu.kinematics.joints import JOINTS, PARAMETERIZATIONS
    text = (DOCS / "scene-format.md").read_text(encoding="utf-8")
    rows = {m.group(1): m.group(0) for m in re.finditer(r"^\| (\w+) \| \d+ \|.*$", text, re.M)}
    for kind, params in PARAMETERIZATIONS.items():
        row = rows[kind] + (rows["spherical"] if "the spherical set" in rows[kind] else "")  # free's row refers to it
        default = JOINTS[(kind, params[0] if params else None)]
        assert row.split("|")[2].strip() == str(default.nvel), row
        for p in params or (None,):
            joint = JOINTS[(kind, p)]
            for name in joint.positions + joint.velocities:
                assert re.search(rf"[ `]\.{name}\b|<body>\.{name}\b", row), (kind, name)
            assert all(f"`{f}" in row for f in joint.fields), (kind, joint.fields)


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_builds_a_valid_fmu(path, tmp_path):
    from fmpy.validation import validate_fmu
    fmu = mbsfmu.build_fmu(path, tmp_path)
    assert validate_fmu(str(fmu)) == []
    t, Y, YD = mbsfmu.simulate(mbsfmu.load(path), stop=0.1, step=0.01)
    assert np.isfinite(Y).all() and np.isfinite(YD).all()


def test_cylindrical_example_follows_its_closed_form():
    """Sleeve on a vertical shaft: m s̈ = −k s − m g, so s = −mg/k + (s0 + mg/k) cos(√(k/m) t); the spin
    about the axis is free and uncoupled (centre of mass on the axis): angle = ω0 t."""
    scene = mbsfmu.load(DOCS / "examples" / "cylindrical.yaml")
    m, k, g, s0, w0 = 0.5, 50.0, 9.81, 0.1, 3.0
    t, Y, YD = mbsfmu.simulate(scene, stop=2.0, step=0.01)
    s_exact = -m * g / k + (s0 + m * g / k) * np.cos(math.sqrt(k / m) * t)
    assert np.abs(Y[:, 0] - s_exact).max() < 1e-7
    assert np.abs(Y[:, 1] - w0 * t).max() < 1e-7


def test_planar_example_follows_its_closed_form():
    """Board tossed in the x-z plane: board.x along world x, board.y along world z (the documented axes),
    board.angle about the normal; gravity acts on board.y only: y = vy t − g t²/2."""
    scene = mbsfmu.load(DOCS / "examples" / "planar.yaml")
    t, Y, YD = mbsfmu.simulate(scene, stop=0.8, step=0.01)
    assert np.abs(Y[:, 0] - 1.0 * t).max() < 1e-8
    assert np.abs(Y[:, 1] - (4.0 * t - 9.81 * t ** 2 / 2)).max() < 1e-8
    assert np.abs(Y[:, 2] - 6.0 * t).max() < 1e-8


def test_parameter_unit_reaches_the_model_description(tmp_path):
    import zipfile
    from xml.etree import ElementTree
    text = (DOCS / "examples" / "prismatic.yaml").read_text(encoding="utf-8").replace(
        "k: {value: 200.0, description: spring stiffness}", "k: {value: 200.0, description: spring stiffness, unit: N/m}")
    try:
        scene = mbsfmu.loads(text)
    except mbsfmu.ModelError as e:
        if "unit" in str(e):
            pytest.skip(f"the scene loader does not accept parameters.unit yet (issue 12): {e}")
        raise
    fmu = mbsfmu.build_fmu(scene, tmp_path)
    root = ElementTree.fromstring(zipfile.ZipFile(fmu).read("modelDescription.xml"))
    real = root.find("ModelVariables/ScalarVariable[@name='k']/Real")
    assert real.get("unit") == "N/m" and real.get("start") == "200.0"
    assert root.find("UnitDefinitions/Unit[@name='N/m']") is not None


def test_start_values_are_shortest_round_trip(tmp_path):
    """0.8 is written as 0.8, not 0.80000000000000004; every start value reads back to the same double."""
    import zipfile
    from xml.etree import ElementTree
    scene = mbsfmu.load(REPO / "models" / "pendulum.yaml")
    fmu = mbsfmu.build_fmu(scene, tmp_path)
    root = ElementTree.fromstring(zipfile.ZipFile(fmu).read("modelDescription.xml"))
    starts = {v.get("name"): v.find("Real").get("start") for v in root.iter("ScalarVariable")
              if v.find("Real") is not None and v.find("Real").get("start") is not None}
    assert starts["L"] == "0.8" and starts["m_rod"] == "0.3"
    for p in scene.spec["parameters"]:
        assert float(starts[p["name"]]) == p["value"]


def _commands(page):
    for block in blocks(page, "bash"):
        for line in block.replace("\\\n", " ").splitlines():  # continued lines joined
            words = shlex.split(line, comments=True)
            if words and words[0] == "mbsfmu":
                yield words[1:]


def test_integrators_page_lists_every_method_with_what_sets_its_accuracy():
    """integrators.md's table has one row per integrator of the engine's table, and its "step" column says
    "adaptive" for a method whose accuracy rtol sets and "fixed" for one whose integrator.step sets
    (mbs_layout.h's MBS_METHODS; the benchmarks sweep each over that)."""
    from mbsfmu.engine.layout import LISTS
    cells = [re.split(r"(?<!\\)\|", ln) for ln in (DOCS / "integrators.md").read_text(encoding="utf-8").splitlines()
             if re.match(r"\| `\w+` \|", ln)]  # cells split at the unescaped |
    rows = {c[1].strip(" `"): c[4].strip() for c in cells}
    assert set(rows) == {e[1] for e in LISTS["MBS_METHODS"]}
    for _, name, _, control in LISTS["MBS_METHODS"]:
        assert rows[name].startswith({"tolerance": "adaptive", "step": "fixed"}[control]), (name, rows[name])


def test_documented_method_lists_are_the_engines():
    """Every place the docs list the integrators (the scene format, the FMU's variable, the CLI's --method) names
    exactly the engine's table, in its order (mbs_layout.h: MBS_METHODS, what the loader accepts)."""
    from mbsfmu.engine.layout import METHODS
    lines = [(p.name, ln) for p in OWN_PAGES for ln in p.read_text(encoding="utf-8").splitlines()
             if ln.startswith("|") and ("integrator.method" in ln or "--method" in ln)]
    assert {p for p, _ in lines} >= {"scene-format.md", "fmu.md", "cli.md"}
    for page, ln in lines:
        assert tuple(re.findall(r"`(\w+)`", ln)) == METHODS, (page, ln)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_documented_commands_parse(page):
    """Every `mbsfmu …` line in the README and docs/ is accepted by the command-line parser."""
    for words in _commands(page):
        try:
            parse(words)
        except SystemExit as e:
            pytest.fail(f"{page.name}: `mbsfmu {' '.join(words)}` does not parse (exit {e.code})")


@pytest.mark.parametrize("name", ["python-api.md", "fmu.md"])
def test_python_pages_run(name, tmp_path, monkeypatch, capsys):
    """The page's python blocks, in order, in one namespace, from a folder that looks like the repository."""
    for d in ("models", "docs"):
        (tmp_path / d).symlink_to(REPO / d)
    monkeypatch.chdir(tmp_path)
    ns = {}
    for code in blocks(DOCS / name, "python"):
        exec(compile(code, name, "exec"), ns)  # our own documentation, not foreign input


def test_readme_python_blocks_compile():
    for code in blocks(REPO / "README.md", "python"):
        compile(code, "README.md", "exec")


@pytest.mark.parametrize("page", OWN_PAGES, ids=lambda p: p.name)
def test_links_resolve(page):
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
        if re.match(r"[a-z]+://", target):
            continue
        path = (page.parent / target).resolve()
        if path.name in PLANNED and path.parent == DOCS:
            continue
        assert path.exists(), f"{page.name}: broken link {target}"


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("MBSFMU_SLOW") != "1", reason="fresh venv + pip install: set MBSFMU_SLOW=1")
def test_fresh_venv_runs_every_readme_command(tmp_path):
    """The README's install command in a new virtual environment, then every README `mbsfmu` command."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py, exe = venv / "bin" / "python", venv / "bin" / "mbsfmu"
    r = subprocess.run([str(py), "-m", "pip", "install", "-q", "-e", str(REPO)], capture_output=True, text=True,
                       timeout=1800)
    assert r.returncode == 0, r.stderr[-3000:]
    work = tmp_path / "work"
    work.mkdir()
    (work / "models").symlink_to(REPO / "models")
    r = subprocess.run([str(py), str(REPO / "build_fmu.py"), "models/double_pendulum.yaml", "-o", "out/"],
                       cwd=work, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    for words in _commands(REPO / "README.md"):
        args = [a for w in words for a in (sorted(str(p.relative_to(work)) for p in work.glob(w)) or [w])]
        r = subprocess.run([str(exe), *args], cwd=work, capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, (words, r.stderr[-3000:])
        assert "Traceback" not in r.stderr


def _variables(fmu):
    from fmpy import read_model_description
    return [(v.name, v.causality, v.variability, v.unit, v.start) for v in read_model_description(str(fmu)).modelVariables]


def test_native_fmu_validates_and_has_the_same_variables(tmp_path):
    """docs/fmu.md: both kinds expose identical variables, the native one then the derivatives of its continuous
    states (model exchange); the native one passes fmpy's validation."""
    import shutil
    from fmpy.validation import validate_fmu
    if shutil.which(os.environ.get("CC", "cc")) is None:
        pytest.skip("native FMUs need a C compiler")
    path = DOCS / "examples" / "cylindrical.yaml"
    native = mbsfmu.build_fmu(path, tmp_path / "native", kind="native")
    assert validate_fmu(str(native)) == []
    python = mbsfmu.build_fmu(path, tmp_path / "python")
    ours, theirs = _variables(native), _variables(python)
    assert ours[:len(theirs)] == theirs
    assert all(name.startswith("der(") and causality == "local" for name, causality, *_ in ours[len(theirs):])
    assert len(ours) - len(theirs) == sum(name.startswith(("y.", "yd.")) for name, *_ in theirs)


def test_limits_are_quoted_from_scene_limits(capsys):
    """`simulate --help`, docs/cli.md and the README state the table rows and result points of limits.py
    (one source), and the table shows at most that many rows."""
    from mbsfmu.cli import _print_table
    from mbsfmu import limits
    with pytest.raises(SystemExit):
        parse(["simulate", "--help"])
    helptext = " ".join(capsys.readouterr().out.split())
    cli_md = " ".join((DOCS / "cli.md").read_text(encoding="utf-8").split())
    readme = " ".join((REPO / "README.md").read_text(encoding="utf-8").split())
    for text in (helptext, cli_md):
        assert f"at most {limits.TABLE_ROWS} rows" in text and f"at most {limits.RESULT_POINTS:,} communication points" in text
    assert f"keeps at most {limits.RESULT_POINTS:,}" in readme
    exponent = "".join("⁰¹²³⁴⁵⁶⁷⁸⁹"[int(d)] for d in str(round(math.log10(limits.COMMUNICATION_POINTS))))
    assert f"≤ 10{exponent} communication points" in readme
    for n in (1, 2, 20, 21, 22, 41, 201, 1000, 1001):
        _print_table(np.arange(n, dtype=float), np.zeros((n, 0)), [])
        rows = capsys.readouterr().out.splitlines()
        shown = [r for r in rows if not r.startswith("#")][1:]  # after the header
        assert shown[-1] == f"{n - 1:g}" and (len(shown) == n if n <= limits.TABLE_ROWS else len(shown) <= limits.TABLE_ROWS)
        assert n <= limits.TABLE_ROWS or rows[0].startswith(f"# showing {len(shown)} of {n} rows")


def test_no_python_block_writes_one_fmu_twice():
    """An FMU is named after its scene: two build_fmu calls of one scene into one folder (say, both kinds into
    out/) silently replace the first; no documented block does that."""
    import ast
    for page in PAGES:
        for code in blocks(page, "python"):
            targets = []
            for call in ast.walk(ast.parse(code)):
                if isinstance(call, ast.Call) and getattr(call.func, "attr", None) == "build_fmu":
                    args = [a.value for a in call.args[:2] if isinstance(a, ast.Constant)]
                    if len(args) == 2:
                        targets.append((Path(args[0]).stem, Path(args[1])))
            assert len(targets) == len(set(targets)), f"{page.name}: {targets}"


# What a documented command reads and writes (argparse attributes of mbsfmu.cli.parse's namespace)
READS = ("scene", "model", "urdf", "fmu", "input", "result")
WRITES = ("output", "csv", "plot", "out", "series")
SHIPPED = ("models", "docs")  # the folders a command may read from: what a fresh checkout has


def _documented_commands(page):
    """(line, argv of mbsfmu) of every runnable command on a page: the `mbsfmu …` and `python3 build_fmu.py …`
    lines of its bash blocks, and inline `mbsfmu …` spans that name no placeholder (SCENE, <head>, …)."""
    text = page.read_text(encoding="utf-8")
    lines = [ln for b in blocks(page, "bash") for ln in b.replace("\\\n", " ").splitlines()]
    lines += [s for s in re.findall(r"`(mbsfmu [^`\n]*)`", text)
              if not re.search(r"…|\.\.\.|<|\b[A-Z]{2,}\b", s)]
    for line in (part for ln in lines for part in ln.split(" && ")):  # each command of a chain
        words = shlex.split(line, comments=True)
        if words[:1] == ["mbsfmu"]:
            yield line, words[1:]
        elif words[:2] == ["python3", "build_fmu.py"]:
            yield line, ["build", *words[2:]]


def _files(line, argv):
    """(files the command reads, files it writes) as paths relative to the repository; a build writes
    DIR/<the scene's name:>.fmu per scene (an FMU is named after its scene, not its file)."""
    try:
        args = parse(argv)
    except SystemExit:
        return None  # an incomplete span (`mbsfmu simulate`): test_documented_commands_parse covers blocks
    reads = [getattr(args, a, None) for a in READS]
    if args.command in ("bench",):
        reads += [w for w in args.rest[:1] if not w.startswith("-")]
    reads = [p for r in reads for p in (r if isinstance(r, list) else [r])
             if isinstance(p, str) and "=" not in p and not p.startswith("tcp://")]
    reads = [str(p.relative_to(REPO)) for r in reads for p in (sorted(REPO.glob(r)) or [REPO / r])]
    writes = [w for a in WRITES for w in [getattr(args, a, None)] if isinstance(w, str)]
    if args.command == "build":
        import yaml
        writes = [str(Path(args.output) / f"{yaml.safe_load((REPO / s).read_text(encoding='utf-8'))['name']}.fmu")
                  for s in reads if (REPO / s).is_file()]
    return reads, [os.path.normpath(w) for w in writes], (getattr(args, "kind", None), getattr(args, "fmi", None))


def _readme_outputs():
    return {w for line, argv in _documented_commands(REPO / "README.md") for w in (_files(line, argv) or ((), (), None))[1]}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_documented_commands_name_files_that_exist(page):
    """Every file a documented command reads is shipped (models/, docs/) or written by a line before it (on its
    page or, for docs/ pages, in the README, which a reader follows first), so each line runs as written from
    the repository's root; and no line replaces an FMU another line of the page built otherwise (both kinds of
    one scene into one folder: the second silently replaces the first)."""
    made = set() if page.name == "README.md" or page.parent != DOCS else _readme_outputs()
    written = {}
    for line, argv in _documented_commands(page):
        files = _files(line, argv)
        if files is None:
            continue
        reads, writes, how = files
        for r in reads:
            shipped = r.split("/")[0] in SHIPPED and (REPO / r).exists()
            assert shipped or os.path.normpath(r) in made, f"{page.name}: `{line.strip()}` reads {r}: not shipped, not written before"
        for w in writes:
            if w.endswith(".fmu") and w in written:
                assert written[w][0] == how, f"{page.name}: `{line.strip()}` replaces {w}, built by `{written[w][1]}`"
            written[w] = how, line.strip()
        made |= set(writes)


def _run_here(tmp_path, monkeypatch):
    for d in SHIPPED:
        (tmp_path / d).symlink_to(REPO / d)
    monkeypatch.chdir(tmp_path)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_documented_check_and_convert_lines_run(page, tmp_path, monkeypatch, capsys):
    """The fast documented commands (check, convert) run as written from the repository's root: exit 0."""
    from mbsfmu.cli import main
    _run_here(tmp_path, monkeypatch)
    for line, argv in _documented_commands(page):
        if argv[:1] in (["check"], ["convert"]) and _files(line, argv) is not None:
            capsys.readouterr()
            assert main(argv) == 0, f"{page.name}: `{line.strip()}`: {capsys.readouterr().err}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_python_blocks_import_what_they_use(page):
    """A reader copies one block: every module a block uses it imports itself, and every other name it reads
    is bound in it or in a block before it on the page (python-api.md's blocks build on each other)."""
    import ast
    import builtins
    modules, bound = set(), set(dir(builtins))
    for code in blocks(page, "python"):
        tree = ast.parse(code)
        imported, here = set(), set()
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                imported |= {(a.asname or a.name).split(".")[0] for a in node.names}
            elif isinstance(node, ast.Name) and isinstance(node.ctx, (ast.Store, ast.Del)):
                here.add(node.id)
            elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                here.add(node.name)
            elif isinstance(node, ast.arg):
                here.add(node.arg)
            elif isinstance(node, ast.ExceptHandler) and node.name:
                here.add(node.name)
        modules |= imported
        used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}
        missing = {n for n in used if n in modules and n not in imported | here}
        missing |= used - modules - bound - imported - here
        assert not missing, f"{page.name}: a python block uses {sorted(missing)} without importing or defining it:\n{code}"
        bound |= imported | here


def test_the_readme_layout_table_is_the_tree():
    """Every path the README's layout table names exists; every folder of the package and every module at its
    top is named there (a row may name several: `errors.py`, `files.py`, ... after a folder's path)."""
    text = (REPO / "README.md").read_text()
    table = text.split("## Layout", 1)[1].split("\n\n", 2)[2].split("\n\n", 1)[0]
    rows = [r.split("|")[1].strip() for r in table.splitlines() if r.startswith("| `")]
    named = set()
    for cell in rows:
        parts = re.findall(r"`([^`]+)`", cell)
        folder = parts[0].rsplit("/", 1)[0] if "/" in parts[0].rstrip("/") and not parts[0].endswith("/") else ""
        for k, p in enumerate(parts):
            path = p if k == 0 or "/" in p else f"{folder}/{p}"
            assert (REPO / path).exists(), f"README's layout names {path}, which does not exist"
            named.add(path.rstrip("/"))
    pkg = REPO / "src" / "mbsfmu"
    wanted = {f"src/mbsfmu/{p.name}" for p in pkg.iterdir()
              if (p.is_dir() and (p / "__init__.py").exists()) or (p.is_dir() and any(p.glob("*.c")))
              or (p.suffix == ".py" and p.name not in ("__init__.py", "__main__.py"))}
    missing = sorted(wanted - named)
    assert not missing, f"not in README's layout table: {missing}"
