"""README.md and the documentation site as a new user meets them: a fresh
virtual environment, ``pip install .`` from a clean copy of the repository
(the README's first command, as written), then every ``bash`` and ``python``
block of the README and of every page of the site, as written, in the site's
order (``mkdocs.yml``'s nav: a how-to may use the file a tutorial made).

Fenced blocks without a language (templates naming a user's own files,
formulas, output) are not run; a page's runnable blocks are fenced ``bash`` or
``python``. The README's test command (this suite) is not run from inside it,
and a block already run word for word (the set-up commands, repeated on the
getting-started page) is not run again, nor an install command already run
(``pip install .`` of the getting-started and live pages: the README's). The blocks write only into scratch
folders that git ignores, and every output file is written with
``--overwrite`` so that a block runs again. Slow: it installs the package and
its dependencies (from pip's cache when there is one) and runs the demo and
the tours.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from _shared import ROOT

import yaml

#: The folders the blocks may create in the repository's root (git ignores them).
SCRATCH = {"tour", "sim", "ti_walk", "mmsnap_demo_out"}


def _nav_pages(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    if isinstance(node, list):
        return [f for item in node for f in _nav_pages(item)]
    if isinstance(node, dict):
        return [f for value in node.values() for f in _nav_pages(value)]
    return []


def pages(root: Path = ROOT) -> list[str]:
    """README.md, then every hand-written page of the site in nav order."""
    nav = _nav_pages(yaml.safe_load((root / "mkdocs.yml").read_text())["nav"])
    return ["README.md"] + [f"docs/{p}" for p in nav if (root / "docs" / p).is_file()]


#: The first line of a block that talks to radar boards: not run here.
NEEDS_HARDWARE = "# needs hardware"


def runnable_blocks(text: str) -> list[tuple[str, str]]:
    """``(language, body)`` of each ``bash`` or ``python`` fenced block, but
    those that open with :data:`NEEDS_HARDWARE` (docs/LIVE.md's)."""
    return [(m.group(1), m.group(2))
            for m in re.finditer(r"^```(bash|python)\n(.*?)^```", text, flags=re.S | re.M)
            if not m.group(2).startswith(NEEDS_HARDWARE)]


def test_runnable_blocks_are_found():
    blocks = runnable_blocks("a\n```bash\nmmsnap demo\n```\n```\nnot run\n```\n"
                             "```python\nimport numpy\n```\n")
    assert blocks == [("bash", "mmsnap demo\n"), ("python", "import numpy\n")]
    assert runnable_blocks("```bash\n# needs hardware\nmmsnap record\n```\n") == []
    assert any("pip install ." in body for _, body in runnable_blocks((ROOT / "README.md")
                                                                      .read_text()))


def test_every_page_of_the_site_is_run():
    found = pages()
    assert found[0] == "README.md" and "docs/TI.md" in found
    assert "docs/tutorials/real-recordings.md" in found and len(found) >= 15


_OUTPUT = re.compile(r"(?:^|\s)(?:-o|--output|--out|--json-out)\s+(\S+)")


def _commands(body: str) -> list[str]:
    return [line for line in body.replace("\\\n", " ").splitlines()
            if line.strip().startswith("mmsnap ")]


@pytest.mark.parametrize("page", pages())
def test_blocks_write_into_scratch_folders_and_can_run_again(page):
    """Each ``mmsnap`` command that writes a file names it inside a scratch
    folder git ignores, with ``--overwrite`` (a second run of the block would
    otherwise stop); no block writes into ``data/``."""
    ignored = (ROOT / ".gitignore").read_text().split()
    for lang, body in runnable_blocks((ROOT / page).read_text()):
        if lang != "bash":
            continue
        for command in _commands(body):
            for out in _OUTPUT.findall(command):
                folder = out.split("/")[0]
                assert "/" in out and folder in SCRATCH, (page, command)
                assert f"/{folder}/" in ignored, f"{folder}/ is not in .gitignore"
                if "demo" not in command.split()[:2]:
                    assert "--overwrite" in command, (page, command)


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
    start = time.perf_counter()
    done = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=1200)
    print(f"{time.perf_counter() - start:6.1f} s  {page}: {body.splitlines()[0][:70]}")
    assert done.returncode == 0, (f"{page} block failed (exit {done.returncode}):\n{body}\n"
                                  f"stdout: {done.stdout[-3000:]}\nstderr: {done.stderr[-3000:]}")


#: What ``pip install .`` itself leaves in the source folder (git ignores them).
PIP_BUILD = {"build", "mmsnap_graph.egg-info"}


def stages(blocks: list[tuple[str, str, str]]) -> list[list[list[tuple[str, str, str]]]]:
    """The ``(page, language, body)`` blocks in stages: a block that runs
    ``pip install`` is a stage of its own (it changes the installation the
    others use); between two such blocks, the blocks go into lanes by the
    scratch folder they use, ``tour/`` or not, each lane in page order. The
    lanes of a stage share no file, so they run side by side."""
    out, current = [], {"tour": [], "other": []}
    for block in blocks:
        if "pip install" in block[2]:
            out += [[lane for lane in current.values() if lane], [[block]]]
            current = {"tour": [], "other": []}
        else:
            current["tour" if "tour/" in block[2] else "other"].append(block)
    out.append([lane for lane in current.values() if lane])
    return [stage for stage in out if stage]


def without_installs_run(body: str, installed: set[str]) -> str:
    """``body`` without the ``pip install`` commands of ``installed`` (those
    already run), which are added to it: the same install of the same source
    again gives the blocks after it nothing new (an editable install of the
    package runs as a copy does), so it is run once. A command is a line, or
    a part of one between ``&&``; a line left without one is dropped."""
    lines = []
    for line in body.splitlines():
        parts = [c.strip() for c in line.split("&&")]
        kept = [c for c in parts if not (c.startswith("pip install") and c in installed)]
        installed.update(c for c in parts if c.startswith("pip install"))
        if kept:
            lines.append(" && ".join(kept) if len(kept) < len(parts) else line)
    return "".join(f"{line}\n" for line in lines)


def test_an_install_already_run_is_not_run_again():
    installed: set[str] = set()
    assert without_installs_run("pip install . && mmsnap demo\n", installed) == (
        "pip install . && mmsnap demo\n")
    assert without_installs_run("pip install .\n", installed) == ""
    assert without_installs_run("pip install .\nmmsnap record --list-ports\n", installed) == (
        "mmsnap record --list-ports\n")
    assert without_installs_run('pip install -e ".[view]"\n', installed) == (
        'pip install -e ".[view]"\n')
    assert installed == {"pip install .", 'pip install -e ".[view]"'}


def test_stages_keep_page_order_and_isolate_installs():
    blocks = [("R", "bash", "pip install ."), ("R", "bash", "mmsnap x tour/a.h5"),
              ("R", "python", "print(1)"), ("T", "bash", "mmsnap y tour/a.h5"),
              ("S", "bash", "pip install -e '.[x]'"), ("S", "python", "print(2)")]
    assert stages(blocks) == [[[blocks[0]]], [[blocks[1], blocks[3]], [blocks[2]]],
                              [[blocks[4]]], [[blocks[5]]]]


@pytest.mark.slow
def test_readme_and_every_page_run_as_written_after_pip_install(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    repo = _clean_copy(tmp_path / "repo")
    venv = tmp_path / "venv"
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    print(f"{time.perf_counter() - start:6.1f} s  python -m venv")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env['PATH']}"
    env["VIRTUAL_ENV"] = str(venv)
    env["MPLBACKEND"] = "Agg"
    before = {p.name for p in repo.iterdir()}
    blocks, seen, installed = [], set(), set()
    for page in pages(repo):
        for lang, body in runnable_blocks((repo / page).read_text()):
            if "pytest" in body or body in seen:
                continue
            seen.add(body)
            if lang == "bash":
                body = without_installs_run(body, installed)
            if body:
                blocks.append((page, lang, body))
    assert len(blocks) >= 20

    def lane(blocks_of_lane):
        for page, lang, body in blocks_of_lane:
            _run(lang, body, repo, env, page)

    with ThreadPoolExecutor(max_workers=2) as pool:
        for stage in stages(blocks):
            for future in [pool.submit(lane, blocks_of_lane) for blocks_of_lane in stage]:
                future.result()
    left = {p.name for p in repo.iterdir()} - before - PIP_BUILD
    assert left <= SCRATCH, f"blocks left files in the repository's root: {sorted(left - SCRATCH)}"
