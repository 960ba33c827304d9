"""Output files (mbsfmu.files, issue 22): no command overwrites one of its inputs or writes two outputs into
one file (refused before any work, one line), and every output appears in one step: a write that fails or is
killed leaves the previous file as it was."""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from mbsfmu import files

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src" / "mbsfmu"
PENDULUM = REPO / "models" / "pendulum.yaml"


def cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "mbsfmu.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=120, cwd=cwd)


def refused(r, *words):
    """One line on stderr, exit 1, no traceback, naming what clashed."""
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    for w in words:
        assert w in r.stderr, r.stderr


@pytest.fixture
def scene(tmp_path):
    p = tmp_path / "pendulum.yaml"
    shutil.copy(PENDULUM, p)
    return p


# Ways one file gets a second name: the same path spelt otherwise, a symlink, a hard link, a symlinked folder.
def _same_path(p):
    return p.parent / "sub" / ".." / p.name


def _symlink(p):
    link = p.parent / "link.csv"
    link.symlink_to(p.name)
    return link


def _hard_link(p):
    link = p.parent / "hard.csv"
    os.link(p, link)
    return link


def _folder_link(p):
    folder = p.parent / "linked"
    folder.symlink_to(p.parent, target_is_directory=True)
    return folder / p.name


ALIASES = [_same_path, _symlink, _hard_link, _folder_link]


@pytest.mark.parametrize("alias", ALIASES)
def test_simulate_csv_over_the_scene_is_refused(scene, alias):
    (scene.parent / "sub").mkdir()
    before = scene.read_bytes()
    r = cli("simulate", scene, "--csv", alias(scene), cwd=scene.parent)
    refused(r, "--csv", "the model")
    assert scene.read_bytes() == before


@pytest.mark.parametrize("alias", ALIASES)
def test_two_outputs_that_are_one_file_are_refused_before_any_work(scene, alias):
    (scene.parent / "sub").mkdir()
    out = scene.parent / "out.csv"
    out.write_text("old\n")
    r = cli("simulate", scene, "--csv", out, "--plot", alias(out), cwd=scene.parent)
    refused(r, "--csv", "--plot", "one file")
    assert out.read_text() == "old\n"  # nothing written: refused before the run


def test_animate_over_its_scene_or_mesh_is_refused(scene):
    mesh = scene.parent / "bob.stl"
    mesh.write_text("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 0.1 0 0\nvertex 0 0.1 0\n"
                    "endloop\nendfacet\nendsolid t\n")
    text = scene.read_text().replace("bodies:", "bodies:", 1)
    with_mesh = scene.parent / "meshed.yaml"
    with_mesh.write_text(re.sub(r"(\n  bob:\n)", r"\1    shape: {type: mesh, file: bob.stl}\n", text, count=1))
    before = {p: p.read_bytes() for p in (scene, mesh, with_mesh)}
    refused(cli("animate", scene, "-o", scene, cwd=scene.parent), "the model")
    r = cli("animate", with_mesh, "-o", "./bob.stl", cwd=scene.parent)
    assert "shape" in with_mesh.read_text() and r.returncode == 1, r.stderr
    refused(r, "the mesh file bob.stl")
    assert {p: p.read_bytes() for p in before} == before


def test_build_of_two_scenes_with_one_model_name_is_refused(scene, tmp_path):
    twin = tmp_path / "twin.yaml"
    shutil.copy(scene, twin)
    r = cli("build", scene, twin, "-o", tmp_path / "out")
    refused(r, "pendulum.fmu", "one file", "different")
    assert not (tmp_path / "out").exists()  # before the first build


def test_build_over_its_own_scene_is_refused(scene, tmp_path):
    named_like_the_fmu = tmp_path / "pendulum.fmu"  # a YAML file whose name is the FMU's
    shutil.copy(scene, named_like_the_fmu)
    r = cli("build", named_like_the_fmu, "-o", tmp_path)
    refused(r, "the scene")
    assert named_like_the_fmu.read_bytes() == scene.read_bytes()


@pytest.mark.parametrize("argv, words", [
    (["--out", "F.csv", "--series", "F.csv"], ["--out", "--series"]),
    (["--out", "F.csv", "--plot", "./F.csv"], ["--out", "--plot"]),
    (["--series", "F.csv", "--out", "link.csv"], ["--series", "--out"]),  # link.csv → F.csv
])
def test_sweep_outputs_clash_refused_before_any_work(scene, argv, words):
    (scene.parent / "link.csv").symlink_to("F.csv")
    r = cli("sweep", scene.name, "--vary", "L=0.5,1", "--scheduler", "inprocess", *argv, cwd=scene.parent)
    refused(r, *words)
    assert not (scene.parent / "F.csv").exists() and scene.read_bytes() == PENDULUM.read_bytes()


# -- one step: the previous file stays until the new one is complete ---------------------------------------
def test_a_failed_write_leaves_the_previous_file_and_no_temporary(tmp_path):
    out = tmp_path / "r.csv"
    out.write_text("previous\n")
    with pytest.raises(KeyboardInterrupt):
        with files.replacing(out) as tmp:
            Path(tmp).write_text("half")
            raise KeyboardInterrupt  # Ctrl-C in the middle of a write
    assert out.read_text() == "previous\n" and os.listdir(tmp_path) == ["r.csv"]


def test_replacing_keeps_permissions_follows_symlinks_and_writes_devices(tmp_path):
    real = tmp_path / "real.csv"
    real.write_text("a")
    real.chmod(0o640)
    link = tmp_path / "link.csv"
    link.symlink_to(real)
    files.write_text(link, "b")
    assert link.is_symlink() and real.read_text() == "b" and (real.stat().st_mode & 0o777) == 0o640
    files.write_text(os.devnull, "nothing")  # a device is written to, never replaced
    assert Path(os.devnull).is_char_device()
    fresh = tmp_path / "new" / "fresh.txt"
    files.write_text(fresh, "c")
    umask = os.umask(0)
    os.umask(umask)
    assert fresh.read_text() == "c" and (fresh.stat().st_mode & 0o777) == 0o666 & ~umask


KILLED_BUILD = """
import os, signal, sys
from mbsfmu.fmu import build, native
native._binary = lambda *args: b"not compiled"  # the writing is under test, not the compiler
real = build.write_zip  # common.write_zip, which each kind imports
def killed(path, members):  # the process dies with the archive half written
    real(path, dict(list(members.items())[:len(members) // 2]))
    os.kill(os.getpid(), signal.SIGKILL)
build.write_zip = native.write_zip = killed
build.build_fmu(sys.argv[1], sys.argv[2], kind=sys.argv[3])
"""


@pytest.mark.parametrize("kind", ["pythonfmu", "native"])
def test_a_build_killed_while_writing_leaves_the_good_fmu(scene, tmp_path, kind, monkeypatch):
    from mbsfmu import build_fmu
    from mbsfmu.fmu import native
    monkeypatch.setattr(native, "_binary", lambda *args: b"not compiled")
    out = tmp_path / "out"
    good = build_fmu(str(scene), out, kind=kind)
    before = good.read_bytes()
    r = subprocess.run([sys.executable, "-c", KILLED_BUILD, str(scene), str(out), kind], capture_output=True,
                       timeout=120, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert r.returncode == -signal.SIGKILL, r.stderr
    assert good.read_bytes() == before
    with zipfile.ZipFile(good) as z:
        assert z.testzip() is None and "modelDescription.xml" in z.namelist()


# -- the class: every writer goes through mbsfmu.files --------------------------------------------------
WRITES = re.compile(r"(?<!files)\.(?:write_text|write_bytes|savefig|savetxt|to_csv|to_parquet)\((\w*)|"
                    r"\bopen\((\w*)[^)]*[\"'][wax]b?\+?[\"']|ZipFile\((\w*)[^)]*[\"']w[\"']")
# Writes that need no mbsfmu.files: into private temporary folders (fmu/build.py: the staged slave resources,
# the shim's C source; fmu/native.py: the sources it compiles; sweep/runner.py: a worker's copy of an FMU;
# bodies/fe_mesh.py: the copy of a mesh file its parser process reads) and into the temporary file of
# files.replacing (fmu/common.py: write_zip; fmu/build.py: _rewrite_zip when the shim goes in).
PRIVATE = {"fmu/build.py": 3, "fmu/common.py": 1, "fmu/native.py": 1, "sweep/runner.py": 1, "bodies/fe_mesh.py": 1}


def test_every_output_goes_through_mbsfmu_files():
    """A new writer that bypasses files.replacing shows up here; the allowance lists the private writes."""
    found = {}
    for path in SRC.rglob("*.py"):
        rel = path.relative_to(SRC).as_posix()
        writes = [m for line in path.read_text().splitlines() for m in WRITES.finditer(line)
                  if not {"tmp", "buf"} & set(m.groups())]  # files.replacing's temporary file; memory
        if writes and rel != "files.py":
            found[rel] = len(writes)
    over = {k: v for k, v in found.items() if v > PRIVATE.get(k, 0)}
    assert not over, f"writes outside mbsfmu.files (use files.replacing / write_text / write_bytes): {over}"
