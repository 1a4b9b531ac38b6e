"""README.md and docs/TI.md as a new user meets them: a fresh virtual
environment, ``pip install .`` from a clean copy of the repository (the
README's first command, as written), then every ``bash`` and ``python`` block
of both pages, as written, in order.

Fenced blocks without a language (templates naming a user's own files,
formulas, output) are not run; a page's runnable blocks are fenced ``bash`` or
``python``. The README's test command (this suite) is not run from inside it.
Slow: it installs the package and its dependencies (from pip's cache when
there is one) and runs the demo and the tour.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from _shared import ROOT

PAGES = ("README.md", "docs/TI.md")


def runnable_blocks(text: str) -> list[tuple[str, str]]:
    """``(language, body)`` of each ``bash`` or ``python`` fenced block."""
    return [(m.group(1), m.group(2))
            for m in re.finditer(r"^```(bash|python)\n(.*?)^```", text, flags=re.S | re.M)]


def test_runnable_blocks_are_found():
    blocks = runnable_blocks("a\n```bash\nmmsnap demo\n```\n```\nnot run\n```\n"
                             "```python\nimport numpy\n```\n")
    assert blocks == [("bash", "mmsnap demo\n"), ("python", "import numpy\n")]
    assert any("pip install ." in body for _, body in runnable_blocks((ROOT / "README.md")
                                                                      .read_text()))


def _clean_copy(dest: Path) -> Path:
    """The repository's tracked files (a clean clone's content) copied to ``dest``."""
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True)
    if listed.returncode != 0:
        pytest.skip("not a git checkout: no clean copy to install from")
    for rel in filter(None, listed.stdout.decode().split("\0")):
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)
    return dest


def _run(lang: str, body: str, cwd: Path, env: dict, page: str) -> None:
    argv = ["bash", "-euo", "pipefail", "-c", body] if lang == "bash" else ["python", "-c", body]
    done = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=1200)
    assert done.returncode == 0, (f"{page} block failed (exit {done.returncode}):\n{body}\n"
                                  f"stdout: {done.stdout[-3000:]}\nstderr: {done.stderr[-3000:]}")


@pytest.mark.slow
def test_readme_and_ti_page_run_as_written_after_pip_install(tmp_path):
    repo = _clean_copy(tmp_path / "repo")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env['PATH']}"
    env["VIRTUAL_ENV"] = str(venv)
    env["MPLBACKEND"] = "Agg"
    ran = 0
    for page in PAGES:
        for lang, body in runnable_blocks((repo / page).read_text()):
            if "pytest" in body:
                continue
            _run(lang, body, repo, env, page)
            ran += 1
    assert ran >= 5
