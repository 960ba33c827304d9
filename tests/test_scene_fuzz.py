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

import pytest

REPO = Path(__file__).resolve().parents[1]
ENGINE = REPO / "src" / "mbsfmu" / "engine"
SAN = ("-fsanitize=address,undefined", "-fno-sanitize-recover=all")
# detect_leaks: a report ends the process on purpose, and what it held is not a leak of the engine
ENV = {"ASAN_OPTIONS": "detect_leaks=0:allocator_may_return_null=0:abort_on_error=0",
       "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1"}
MAX_REPORTS = 30


def _cc():
    return os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")


def build(out: Path, feats=("expr", "elastic")) -> Path | None:
    """The harness with the engine parts `feats`, sanitized; None if the compiler lacks the sanitizers."""
    sys.path.insert(0, str(REPO / "src"))
    from mbsfmu.engine.build import sources

    cc = _cc()
    if cc is None:
        return None
    probe = out.parent / "probe.c"
    probe.write_text("int main(void) { return 0; }\n")
    if subprocess.run([cc, *SAN, str(probe), "-o", str(out.parent / "probe")], capture_output=True).returncode:
        return None
    srcs, _, defs = sources(feats)
    cmd = [cc, "-O1", "-g", "-std=c99", *SAN, *defs, f"-I{ENGINE}", "-o", str(out),
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
    while len(reports) < MAX_REPORTS:
        res = subprocess.run([str(harness), str(first), *map(str, scenes)], capture_output=True, text=True, env=env,
                             timeout=600)
        bad += [line for line in res.stdout.splitlines() if line.startswith("FUZZ-BAD")]
        done = re.search(r"^FUZZ cases (\d+) refused (\d+) ran (\d+) failed (\d+) abandoned (\d+) maxms ([\d.]+) "
                         r"maxalloc (\d+)", res.stdout, re.M)
        if done:
            for key, v in zip(("cases", "refused", "ran", "failed", "abandoned", "maxms", "maxalloc"), done.groups()):
                v = float(v) if key == "maxms" else int(v)
                totals[key] = max(totals.get(key, 0), v) if key.startswith("max") else totals.get(key, 0) + v
            break
        case = struct.unpack("<q", progress.read_bytes()[:8])[0]
        lines = [ln for ln in res.stderr.splitlines() if "ERROR" in ln or "runtime error" in ln or "#" in ln]
        reports.append((case, "\n".join(lines[:8])))
        first = case + 1
    totals["reports"] = len(reports)
    totals["cases"] = totals.get("cases", 0) + len(reports)
    return {"totals": totals, "reports": reports, "bad": bad}


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    return shipped_scenes(tmp_path_factory.mktemp("scenes"))


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
            print("+".join(feats), r["totals"], f"{time.perf_counter() - t0:.1f} s")
            for c, text in r["reports"]:
                print(f"--- case {c}\n{text}")
            print("\n".join(r["bad"][:40]))
