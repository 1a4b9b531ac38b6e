"""Writes the site's generated reference pages at build time (mkdocs-gen-files):

- ``reference/cli.md`` from the ``mmsnap`` argparse parser
  (``mmsnap_graph.app.cli.build_parser``), so it follows every change of a
  command, an option or an argument group;
- ``reference/api/<package>.md``, one page per package of the library, with
  every public module's docstrings (mkdocstrings).

A package missing from :data:`API_PAGES` stops the build: add it here and to
the ``nav`` of ``mkdocs.yml``.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
from pathlib import Path

import mkdocs_gen_files

sys.path.insert(0, str(Path(__file__).parent))
from cli_markdown import cli_reference  # noqa: E402

#: API page -> (title, packages it documents, modules left out (internals)).
API_PAGES = {
    "factors": ("factors: measurement models and GTSAM factors", ["factors"]),
    "data": ("Data types", ["mmsnap_graph.data", "mmsnap_graph.errors"]),
    "fusion": ("One-shot fusion", ["mmsnap_graph.fusion"]),
    "calibration": ("Self-calibration", ["mmsnap_graph.calibration"]),
    "tracking": ("Tracking", ["mmsnap_graph.tracking"]),
    "evaluation": ("Evaluation", ["mmsnap_graph.evaluation"]),
    "radar": ("Radar signal chain", ["mmsnap_graph.radar"]),
    "sim": ("Simulator", ["mmsnap_graph.sim"]),
    "io": ("Files and TI formats", ["mmsnap_graph.io"]),
    "app": ("Application (pipeline, batch, reports)", ["mmsnap_graph.app"]),
}
#: Modules of the command line's own plumbing (the CLI page documents them).
SKIP = ("mmsnap_graph.app.commands", "mmsnap_graph.app.demo")


def public_modules(package: str) -> list[str]:
    """``package`` and its public modules, depth first, in name order."""
    mod = importlib.import_module(package)
    names = [package]
    if hasattr(mod, "__path__"):
        for info in sorted(pkgutil.walk_packages(mod.__path__, package + "."),
                           key=lambda m: m.name):
            parts = info.name.split(".")
            if any(p.startswith("_") for p in parts) or info.name.startswith(SKIP):
                continue
            names.append(info.name)
    return names


def check_every_package_has_a_page() -> None:
    covered = {p for _, packages in API_PAGES.values() for p in packages}
    import mmsnap_graph

    found = {f"mmsnap_graph.{m.name}" for m in pkgutil.iter_modules(mmsnap_graph.__path__)
             if not m.name.startswith("_") and m.ispkg} | {"factors"}
    missing = sorted(found - covered)
    if missing:
        raise SystemExit(f"docs/_gen/reference_pages.py: no API page for {missing}: add one to "
                         "API_PAGES and to the nav of mkdocs.yml")


def api_page(title: str, packages: list[str]) -> str:
    lines = [f"# {title}", ""]
    for package in packages:
        for name in public_modules(package):
            lines += [f"::: {name}", ""]
    return "\n".join(lines)


check_every_package_has_a_page()
for page, (title, packages) in API_PAGES.items():
    with mkdocs_gen_files.open(f"reference/api/{page}.md", "w") as f:
        f.write(api_page(title, packages))
with mkdocs_gen_files.open("reference/cli.md", "w") as f:
    f.write(cli_reference())
