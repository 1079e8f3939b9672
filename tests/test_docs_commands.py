"""Every `ltmap` command shown in the README and docs/ runs as written and does what its text
says: the exit status a trailing ``# exit N`` comment names (else 0), and a ``# path length X m``
comment matches what `ltmap plan` prints. Commands with placeholders (LOG, OUTDIR, [--opt]) are
synopses and are not run. Each document's commands run in order in one fresh folder that holds
``sample_logs`` (and ``../shared`` when it exists), as in a clone of the repository."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PLACEHOLDER = re.compile(r"\b[A-Z]{3,}[A-Z_.]*\b|\[-")


def doc_commands(path: Path) -> list[tuple[str, str]]:
    """(command, trailing comment) of the ``ltmap`` commands of the sh/bash blocks of ``path``
    (a line's commands chained with ``&&`` taken one by one, as the README's install line)."""
    out, block = [], None
    for line in path.read_text().splitlines():
        fence = line.strip()
        if block is None and fence in ("```sh", "```bash"):
            block = []
        elif block is not None and fence == "```":
            text = "\n".join(block).replace("\\\n", " ")
            for line in text.splitlines():
                line, _, comment = line.partition("#")
                for cmd in line.split("&&"):
                    if cmd.strip().startswith("ltmap ") and not PLACEHOLDER.search(cmd):
                        out.append((" ".join(cmd.split()), comment.strip()))
            block = None
        elif block is not None:
            block.append(line.strip())
    return out


CASES = [(p, cmds) for p in DOCS if (cmds := doc_commands(p))]


def test_the_docs_show_runnable_commands():
    assert sum(len(c) for _, c in CASES) >= 6
    assert any("plan" in c for _, cmds in CASES for c, _ in cmds)


@pytest.mark.slow
@pytest.mark.parametrize("doc, commands", CASES, ids=[p.name for p, _ in CASES])
def test_doc_commands_run_as_the_text_says(tmp_path, doc, commands):
    work = tmp_path / "repo"
    work.mkdir()
    (work / "sample_logs").symlink_to(ROOT / "sample_logs")
    if SHARED.exists():
        (tmp_path / "shared").symlink_to(SHARED)
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    ran = 0
    for cmd, comment in commands:
        if "../shared/" in cmd and not SHARED.exists():
            continue
        args = shlex.split(cmd)
        r = subprocess.run([sys.executable, "-m", "ltmap_cli", *args[1:], *(["-q"] if args[1] == "replay" else [])],
                           cwd=work, env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
        want = int(m.group(1)) if (m := re.search(r"exit (\d)", comment)) else 0
        assert r.returncode == want, f"{doc.name}: {cmd}\n{r.stdout}\n{r.stderr}"
        if m := re.search(r"path length ([\d.]+) m", comment):
            got = re.search(r"path length:\s+([\d.]+) m", r.stdout)
            assert got and float(got.group(1)) == pytest.approx(float(m.group(1)), abs=0.01), r.stdout
        ran += 1
    if ran == 0:
        pytest.skip(f"{doc.name}: every command needs ../shared/real_logs")
