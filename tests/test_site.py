"""The documentation site (``mkdocs.yml``, ``docs/``): it builds in strict
mode (a broken link, anchor, nav entry or docstring fails), its command-line
reference is generated from the ``mmsnap`` parser, every page is in the nav,
and the README, ``LICENSE`` and ``CITATION.cff`` say what the package says."""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import subprocess
import sys
import tomllib

import pytest
import yaml

from _shared import ROOT
from mmsnap_graph.app.cli import build_parser

DOCS = ROOT / "docs"


def _needs(module: str):
    """The docs extra's modules: CI installs them (the test extra includes
    the docs extra), so there a missing one fails instead of skipping."""
    if os.environ.get("CI"):
        return importlib.import_module(module)
    return pytest.importorskip(module)


def _gen_module(name: str):
    spec = importlib.util.spec_from_file_location(name, DOCS / "_gen" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _commands(parser: argparse.ArgumentParser, prefix: str = "mmsnap"):
    """(``"mmsnap import table"``, its parser) for every command, nested ones too."""
    yield prefix, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield from _commands(child, f"{prefix} {name}")


def test_cli_reference_has_every_command_and_option_of_the_parser():
    text = _gen_module("cli_markdown").cli_reference()
    commands = list(_commands(build_parser()))
    assert len(commands) >= 14
    missing = []
    for name, parser in commands:
        if f"`{name}`" not in text:
            missing.append(name)
        for action in parser._actions:
            for option in action.option_strings:
                if option not in ("-h", "--help") and action.help != argparse.SUPPRESS \
                        and f"`{option}" not in text and f", {option}" not in text:
                    missing.append(f"{name} {option}")
    assert not missing, missing


def test_cli_reference_escapes_markdown_outside_code():
    md = _gen_module("cli_markdown")
    assert md._text("a *b* `c*d` <e>") == r"a \*b\* `c*d` \<e\>"


def _nav_files(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    if isinstance(node, list):
        return [f for item in node for f in _nav_files(item)]
    if isinstance(node, dict):
        return [f for value in node.values() for f in _nav_files(value)]
    return []


def _config() -> dict:
    return yaml.safe_load((ROOT / "mkdocs.yml").read_text())


def test_every_page_is_in_the_nav_and_every_nav_entry_exists_or_is_generated():
    nav = set(_nav_files(_config()["nav"]))
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")
             if not p.relative_to(DOCS).as_posix().startswith("_gen/")}
    generated = {f"reference/api/{page}.md" for page in _gen_module_api_pages()} | {
        "reference/cli.md"}
    assert pages - nav == set(), "pages missing from the nav of mkdocs.yml"
    assert nav - pages - generated == set(), "nav entries without a page"


def _gen_module_api_pages() -> list[str]:
    """The API pages the build script writes (read from its source: it needs
    mkdocs-gen-files to run)."""
    source = (DOCS / "_gen" / "reference_pages.py").read_text()
    block = source.split("API_PAGES = {", 1)[1].split("\n}", 1)[0]
    return re.findall(r'^    "(\w+)":', block, flags=re.M)


def test_every_library_package_has_an_api_page():
    import pkgutil

    import mmsnap_graph

    pages = set(_gen_module_api_pages())
    packages = {m.name for m in pkgutil.iter_modules(mmsnap_graph.__path__)
                if m.ispkg and not m.name.startswith("_")}
    assert packages <= pages | {"data"} and "factors" in pages


@pytest.mark.slow
def test_site_builds_in_strict_mode(tmp_path):
    _needs("mkdocs")
    _needs("mkdocstrings")
    _needs("mkdocs_gen_files")
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "DISABLE_MKDOCS_2_WARNING": "true"}
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q",
                           "-d", str(site)], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    cli = (site / "reference" / "cli" / "index.html").read_text()
    for name, _ in _commands(build_parser()):
        assert name in cli, name
    fusion = (site / "reference" / "api" / "fusion" / "index.html").read_text()
    assert "FrameProblem" in fusion and "FusionOptions" in fusion
    assert ":class:" not in fusion, "Sphinx roles left raw in the API reference"
    for page in ("index.html", "validation/index.html", "tutorials/real-recordings/index.html"):
        assert (site / page).is_file(), page


# ------------------------------------------------- README, LICENSE, CITATION.cff

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_readme_is_short_and_shows_the_figure_it_makes():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 180, "the README is the front page: keep it about 150 lines"
    figure = re.search(r"!\[[^\]]*\]\((docs/figures/[\w.]+\.png)\)", text).group(1)
    assert (ROOT / figure).is_file()
    assert f"python docs/figures/{figure.split('/')[-1].replace('.png', '.py')}" in text


def test_licence_file_matches_the_package_metadata():
    assert PYPROJECT["project"]["license"]["text"] == "BSD-3-Clause"
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("BSD 3-Clause License")
    assert "Neither the name of the copyright holder" in text
    assert (ROOT / "data" / "real" / "darksz" / "LICENSE").read_text().startswith("MIT License")


def test_citation_file_cites_the_software_and_the_paper():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert cff["version"] == PYPROJECT["project"]["version"]
    assert cff["license"] == PYPROJECT["project"]["license"]["text"]
    paper = cff["preferred-citation"]
    assert paper["title"].startswith("mmSnap: Bayesian One-Shot Fusion")
    assert len(paper["authors"]) == 7
    assert all(a["family-names"] and a["given-names"] for a in paper["authors"])
