"""The compiled engine's cache (engine/build.py): code is loaded only from a directory of the user's that no one
else can write, and only the library that was built there (its sha256 beside it); a library planted under the
name a cache would use (a hash of public sources), in a directory someone else owns or can write, or with other
bytes than were built, is never the one returned, it is built again where that is safe. $MBSFMU_CACHE that cannot
be such a directory is one clear message.

The builds here are a stand-in compiler ($CC: a script writing "built" as its output), so each case takes
milliseconds; what matters is which bytes library_path() hands to the loader.
"""
from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

import pytest

from mbsfmu.engine import build
from mbsfmu.errors import EngineUnavailable

REPO = Path(__file__).resolve().parents[1]
UID = os.getuid() if hasattr(os, "getuid") else 0
pytestmark = pytest.mark.skipif(not hasattr(os, "getuid"), reason="owners and modes are POSIX")

NAME = f"libmbsfmu_engine_{build._tag()}{sysconfig.get_config_var('SHLIB_SUFFIX') or '.so'}.1"


@pytest.fixture
def env(tmp_path, monkeypatch):
    """HOME where ~/.cache/mbsfmu cannot be made (mkdir refused: /sys, even for root; else a path under a regular
    file), TMPDIR in tmp_path, $CC the stand-in compiler, no $MBSFMU_CACHE, no directory of this process's own."""
    cc = tmp_path / "cc"
    cc.write_text('#!/bin/sh\nwhile [ $# -gt 0 ]; do [ "$1" = -o ] && printf built > "$2"; shift; done\n')
    cc.chmod(0o755)
    (tmp_path / "home").write_text("a file, not a directory")
    (tmp_path / "tmp").mkdir(mode=0o700)
    monkeypatch.setenv("HOME", "/sys/mbsfmu-no-home" if os.path.isdir("/sys") else str(tmp_path / "home"))
    monkeypatch.setenv("CC", str(cc))
    monkeypatch.delenv("MBSFMU_CACHE", raising=False)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    monkeypatch.setattr(build, "_SCRATCH", None, raising=False)
    return tmp_path


def plant(d, mode=0o700, owner=None, digest=None):
    """A library 'planted' under the cache's name in d (made with mode; owner: chown it and its contents)."""
    d.mkdir(exist_ok=True)
    (d / NAME).write_bytes(b"planted")
    if digest is not None:
        (d / f"{NAME}.sha256").write_text(digest)
    if owner is not None:
        for p in (d, *d.iterdir()):
            os.chown(p, owner, -1)
    d.chmod(mode)
    return d


def sha(data):
    import hashlib
    return hashlib.sha256(data).hexdigest()


@pytest.mark.parametrize("mode", [0o777, 0o770, 0o702])
def test_planted_library_in_a_directory_others_can_write_is_not_loaded(env, mode):
    """The fallback $TMPDIR/mbsfmu-<uid> made by someone else beforehand, writable by its group or others, the
    library and a matching sha256 in it: not used; the library is built in a directory of this process's own
    (before: the planted one was returned and loaded)."""
    plant(env / "tmp" / f"mbsfmu-{UID}", mode, digest=sha(b"planted"))
    path = build.library_path()
    assert path.read_bytes() == b"built" and path.parent != env / "tmp" / f"mbsfmu-{UID}"
    assert (path.parent.stat().st_mode & 0o777) == 0o700 and path.parent.stat().st_uid == UID


def test_fallback_that_is_a_symbolic_link_is_not_followed(env):
    """$TMPDIR/mbsfmu-<uid> a symbolic link (whoever made it can point it elsewhere between the check and the
    load) to a private directory holding a library and its digest: not used."""
    target = plant(env / "elsewhere", 0o700, digest=sha(b"planted"))
    (env / "tmp" / f"mbsfmu-{UID}").symlink_to(target)
    path = build.library_path()
    assert path.read_bytes() == b"built" and path.parent not in (target, env / "tmp" / f"mbsfmu-{UID}")


@pytest.mark.skipif(UID != 0, reason="planting as another user needs chown (root)")
def test_planted_library_in_a_directory_of_another_user_is_not_loaded(env):
    plant(env / "tmp" / f"mbsfmu-{UID}", 0o755, owner=65534, digest=sha(b"planted"))
    path = build.library_path()
    assert path.read_bytes() == b"built" and path.parent != env / "tmp" / f"mbsfmu-{UID}"


@pytest.mark.parametrize("case", ["no digest", "another digest", "file writable by others", "symbolic link"]
                         + (["file of another user"] if UID == 0 else []))
def test_library_not_as_built_is_built_again(env, case):
    """In the user's own cache ($TMPDIR/mbsfmu-<uid>, 0o700): a library without the digest written at its build,
    with bytes that are not the digest's, writable by others, a symbolic link, or another user's file, is
    replaced by a new build in the same place; as built, it is used as it is."""
    d = plant(env / "tmp" / f"mbsfmu-{UID}", digest=None if case == "no digest" else
              sha(b"other") if case == "another digest" else sha(b"planted"))
    if case == "file writable by others":
        (d / NAME).chmod(0o666)
    if case == "symbolic link":
        (env / "elsewhere").write_bytes(b"planted")
        (d / NAME).unlink()
        (d / NAME).symlink_to(env / "elsewhere")
    if case == "file of another user":
        os.chown(d / NAME, 65534, -1)
    assert build.library_path() == d / NAME and (d / NAME).read_bytes() == b"built"
    assert (d / f"{NAME}.sha256").read_text() == sha(b"built")
    (d / NAME).write_bytes(b"changed later")  # the next process finds other bytes than were built
    assert build.library_path().read_bytes() == b"built"
    os.utime(d / NAME, (0, 0))  # as built: used, not built again
    assert build.library_path() == d / NAME and (d / NAME).stat().st_mtime == 0


@pytest.mark.parametrize("case", ["regular file", "writable by others", "under a regular file"])
def test_mbsfmu_cache_that_cannot_hold_code_is_one_clear_message(env, monkeypatch, case):
    """$MBSFMU_CACHE a regular file, a directory others can write, a path under a regular file: EngineUnavailable
    naming it and why (before: a FileExistsError traceback, or the directory used)."""
    target = {"regular file": env / "file", "writable by others": env / "shared",
              "under a regular file": env / "file" / "cache"}[case]
    (env / "file").write_text("x")
    (env / "shared").mkdir(mode=0o777)
    (env / "shared").chmod(0o777)
    monkeypatch.setenv("MBSFMU_CACHE", str(target))
    with pytest.raises(EngineUnavailable, match=r"\$MBSFMU_CACHE \(.*\) cannot hold the compiled engine: "
                                                r"(not a directory|writable by its group and others \(mode 777\))"):
        build.library_path()


def test_mbsfmu_cache_a_file_on_the_command_line_is_one_line(tmp_path):
    """The CLI with $MBSFMU_CACHE a regular file: exit status 1, one line saying so, no traceback."""
    (tmp_path / "file").write_text("x")
    r = subprocess.run([sys.executable, "-m", "mbsfmu", "simulate", str(REPO / "models" / "pendulum.yaml")],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path,
                       env=dict(os.environ, MBSFMU_CACHE=str(tmp_path / "file")))
    assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "MBSFMU_CACHE" in lines[0] and "not a directory" in lines[0], r.stderr
