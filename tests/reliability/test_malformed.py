"""Malformed scenario, spec and plan files (tests/data/malformed, see make_corpus.py there).

Each file goes through the command that reads it (``gcs plan``, ``gcs verify``
or ``gcs fly --dry-run``): exit 2 with exactly one stderr line naming the file
and the field, no traceback; a plan file edited by hand so that it breaks its
own limits, separation, workspace, start or spec gives ``gcs verify`` exit 1
naming the violated check.  YAML is only ever read with safe loaders.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from gcs.cli import main

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT / "tests" / "data" / "malformed"
MANIFEST: dict[str, dict[str, object]] = json.loads(
    (CORPUS / "manifest.json").read_text(encoding="utf-8")
)
PWNED = Path("/tmp/stl_gcs_pwned")


def cases() -> list[object]:
    out = []
    for name, exp in sorted(MANIFEST.items()):
        marks = []
        if "defect" in exp:
            marks.append(pytest.mark.xfail(strict=True, reason=str(exp["defect"])))
        out.append(pytest.param(name, exp, id=name, marks=marks))
    return out


def test_corpus_is_large_and_covers_every_command() -> None:
    assert len(MANIFEST) >= 40
    assert {e["cmd"] for e in MANIFEST.values()} == {"plan", "verify", "fly"}
    assert sum(e["exit"] == 1 for e in MANIFEST.values()) >= 5  # hand-edited plans
    for name in MANIFEST:
        assert (CORPUS / name).is_file(), name


@pytest.mark.parametrize(("name", "exp"), cases())
def test_malformed_file_gives_one_clear_line_or_names_the_violation(
    name: str, exp: dict[str, object], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = str(CORPUS / name)
    if exp["cmd"] == "plan":
        argv = ["plan", path, "-o", str(tmp_path / "out.plan.json")]
    elif exp["cmd"] == "verify":
        argv = ["verify", path]
    else:
        argv = ["fly", path, "--dry-run"]
    code = main(argv)
    out, err = capsys.readouterr()
    assert code == exp["exit"], (code, err)
    needle = str(exp["needle"])
    if code == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1, err
        assert lines[0].startswith(f"gcs {exp['cmd']}: error: ") and path in lines[0]
        assert needle in lines[0] and "Traceback" not in err
        assert not (tmp_path / "out.plan.json").exists()  # nothing written for bad input
    else:
        failed = [line for line in out.splitlines() if line.startswith("FAIL ")]
        assert failed and any(needle in line for line in failed), out
        assert out.strip().splitlines()[-1].startswith("FAILED: ")


@pytest.mark.slow
def test_python_tags_are_refused_in_a_real_process_and_nothing_runs() -> None:
    PWNED.unlink(missing_ok=True)
    for name in ("s_python_object_tag.yaml", "s_python_tag_in_field.yaml"):
        proc = subprocess.run(
            [sys.executable, "-m", "gcs.cli", "plan", str(CORPUS / name), "-o", "/dev/null"],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=120,
        )
        assert proc.returncode == 2 and "could not determine a constructor" in proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr
    assert not PWNED.exists()


def test_no_unsafe_yaml_loader_in_the_packages() -> None:
    unsafe = re.compile(
        r"yaml\.(load|load_all|full_load|full_load_all|unsafe_load|unsafe_load_all)\s*\("
        r"|Loader\s*=\s*(yaml\.)?(Loader|FullLoader|UnsafeLoader|CLoader|CFullLoader|CUnsafeLoader)\b"
    )
    hits = []
    for pkg in ("planner", "mavlink", "gcs", "benchmarks"):
        for py in sorted((ROOT / pkg).rglob("*.py")):
            for i, line in enumerate(py.read_text(encoding="utf-8").splitlines(), start=1):
                if unsafe.search(line):
                    hits.append(f"{py.relative_to(ROOT)}:{i}: {line.strip()}")
    assert hits == []
    # the check itself finds what it must
    assert unsafe.search("data = yaml.load(text, Loader=yaml.FullLoader)")
    assert unsafe.search("yaml.unsafe_load(s)") and not unsafe.search("yaml.safe_load(s)")
