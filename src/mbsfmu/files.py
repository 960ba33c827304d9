"""Output files: each is written to a temporary file in its target folder and renamed into place, so a run
that fails or is killed leaves the old file (or none), never a half-written one; and no output may be one of
the inputs or another output, checked before any work (issue 22).

Every file a command or the API writes (CSV, plots, HTML pages, FMUs, reports, sweep tables) goes through
``check`` and ``replacing`` (or ``write_bytes`` / ``write_text``).
"""

import contextlib
import os
import secrets
import stat


def _key(path):
    """The file a path names: symlinks and '..' resolved (the folder too when the file does not exist yet)."""
    return os.path.normcase(os.path.realpath(os.fspath(path)))


def _same(a, b):
    """True when paths a and b are one file: one resolved path, or one inode (hard links)."""
    if _key(a) == _key(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet): only the resolved paths can tell
        return False


def check(outputs, inputs=None, hint="choose two files"):
    """Refuse (ValueError, one line) an output that is one of the inputs, or two outputs that are one file.

    outputs, inputs: {label: path} (a label says where the path came from, e.g. "--csv" or "the scene");
    None paths are skipped. hint: what to do about two outputs that are one file."""
    outs = [(label, p) for label, p in outputs.items() if p is not None]
    ins = [(label, p) for label, p in (inputs or {}).items() if p is not None]
    for i, (label, path) in enumerate(outs):
        if os.path.isdir(path):
            raise ValueError(f"{label} {path} is a folder: give a file name")
        for in_label, in_path in ins:
            if _same(path, in_path):
                raise ValueError(f"{label} {path} is {in_label} {in_path}: writing it would destroy the "
                                 "input; choose another output file")
        for other_label, other in outs[i + 1:]:
            if _same(path, other):
                raise ValueError(f"{label} and {other_label} are one file, {other}: the second would "
                                 f"overwrite the first; {hint}")


@contextlib.contextmanager
def replacing(path):
    """Yield a temporary path in the folder of `path` (same suffix, so writers that go by the suffix pick the
    same format); when the block ends without an exception it is renamed to `path` in one step, otherwise
    removed. A symlink at `path` is followed: the file it points to is replaced. A device or FIFO (/dev/null,
    a pipe) is written directly: it cannot be replaced, and it holds no file to lose."""
    target = os.path.realpath(os.fspath(path))
    st = _stat(target)
    if st is not None and stat.S_ISDIR(st.st_mode):  # before the writer's work, not at the rename
        raise IsADirectoryError(21, "is a folder, not a file", os.fspath(path))
    if st is not None and not stat.S_ISREG(st.st_mode):
        yield target
        return
    folder, name = os.path.split(target)
    os.makedirs(folder or ".", exist_ok=True)
    tmp = os.path.join(folder, f".~{secrets.token_hex(4)}~{name}")
    mode = stat.S_IMODE(st.st_mode) if st is not None and stat.S_ISREG(st.st_mode) else None
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask applies, as for a plain open()
    os.close(fd)
    try:
        yield tmp
        if mode is not None:  # replacing a file keeps its permissions, as writing over it would
            os.chmod(tmp, mode)
        with open(tmp, "rb+") as f:  # on disk before the rename: a crash of the machine leaves old or new
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _stat(path):
    try:
        return os.stat(path)
    except OSError:
        return None


def write_bytes(path, data):
    with replacing(path) as tmp, open(tmp, "wb") as f:
        f.write(data)
    return path


def write_text(path, text, encoding="utf-8"):
    return write_bytes(path, text.encode(encoding))
