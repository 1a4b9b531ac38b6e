#!/usr/bin/env python3
"""Check the structure rules of the redesign (docs/CONVENTIONS.md, "Layers").

Run it from anywhere::

    python tools/check_structure.py            # the repository this file lives in
    python tools/check_structure.py --root DIR # another tree with factors/ and mmsnap_graph/

or import it (``check(root) -> Report``). Standard library only: it parses the
sources with :mod:`ast` and imports nothing of the project.

Hard rules (a violation makes the exit code 1):

- ``function-length``: no function or method over ``MAX_FUNCTION_LINES`` lines
  (from its ``def`` line to its last line);
- ``module-length``: no module over ``MAX_MODULE_LINES`` lines;
- ``layer-order``: imports flow one way through the layers of ``LAYERS``
  (factors <- data, errors and the private ``_*.py`` helpers <- evaluation
  <- {fusion, calibration, tracking, radar, sim} <- io <- app); ``radar`` imports
  neither GTSAM nor ``tracking``; ``factors`` never imports ``mmsnap_graph``;
  a package of ``IMPORT_CEILING`` imports nothing above its ceiling (``io``
  only the factors and the data layer: it reads and writes the data layer's
  records and sits below the estimators, which do not import it either);
- ``package-cycle``: no import cycle between packages (peers of the middle
  layer may import each other, but not both ways, directly or round about);
- ``private-import``: no ``from module import _name`` of a private name
  defined in another project module (private helper *modules* such as
  ``mmsnap_graph._validation`` are fine: their names are public);
- ``model-count``: at most ``MAX_MODEL_DEFINITIONS`` definitions of the
  measurement model in ``factors/``: functions whose name matches
  ``MODEL_NAME_PATTERN`` and that compute the model themselves (a function
  that calls another of them is a wrapper derived from it and is listed, not
  counted).

Every import counts, at module level or inside a function, ``if
TYPE_CHECKING:`` blocks included. Reported but not enforced: the
function-level imports of the project's own modules (allowed where they keep
GTSAM, scikit-learn, matplotlib or h5py out of a light import path) and the
import cycles between modules of one package (function-level imports
included: they hide a cycle, they do not remove it).
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "MAX_FUNCTION_LINES",
    "MAX_MODULE_LINES",
    "MAX_MODEL_DEFINITIONS",
    "MAX_PUBLIC_PARAMETERS",
    "MAX_FOLDER_MODULES",
    "MIN_TESTED_SHARE",
    "PENDING_RULES",
    "test_file_of",
    "MODEL_NAME_PATTERN",
    "LAYERS",
    "IMPORT_CEILING",
    "HARD_RULES",
    "Violation",
    "Import",
    "Report",
    "check",
    "format_report",
    "main",
]

MAX_FUNCTION_LINES = 100
MAX_MODULE_LINES = 650
MAX_MODEL_DEFINITIONS = 3

#: Names of the functions that compute ``(range, omega, doppler)`` from a
#: state and a pose (leading underscores ignored): the vector form, the pose
#: form, the scalar kernel and any other variant that would creep back in --
#: a name with ``measurement``, ``predict`` or ``kernel`` in it, or
#: ``range_model``/``omega_model``/``doppler_model`` -- but not the GTSAM
#: adapters around the model (``*factor*``, ``*noise*``, ``*error*``) nor
#: constants (``*names*``).
MODEL_NAME_PATTERN = re.compile(
    r"^(?!.*(?:factor|noise|error|names))"
    r".*(?:(?:range|omega|doppler)_model|measurement|predict|kernel|model_scalar).*$"
)

#: The project's top-level packages, which the checker scans.
TOP_PACKAGES = ("factors", "mmsnap_graph")

#: Layer of each package (a lower number is a lower layer). Imports go from a
#: higher layer to a lower one, or within one package, or between peers of the
#: middle layer (then ``package-cycle`` forbids a cycle).
LAYERS = {
    "factors": 0,
    "mmsnap_graph.data": 1,
    "mmsnap_graph.errors": 1,
    # every private helper module mmsnap_graph/_*.py is layer 1 too (see _package_of)
    # metrics sit between the data and the estimators: the estimators' tests
    # and the app share them, and they import neither
    "mmsnap_graph.evaluation": 1.5,
    "mmsnap_graph.fusion": 2,
    "mmsnap_graph.calibration": 2,
    "mmsnap_graph.tracking": 2,
    "mmsnap_graph.radar": 2,
    "mmsnap_graph.sim": 2,
    "mmsnap_graph.io": 3,
    "mmsnap_graph.app": 4,
    # the package's own __init__ re-exports the public names of every layer
    "mmsnap_graph": 5,
}
LAYER_NAMES = {0: "factors", 1: "data", 1.5: "metrics", 2: "estimation/radar/sim", 3: "io", 4: "app", 5: "mmsnap_graph"}

#: Package -> the highest layer it may import, lower than its place in
#: ``LAYERS`` allows. The file formats read and write the data layer's
#: records (a calibration's, a fused table's, a noise estimate's), so ``io``
#: sits below the estimators as well as above them: it imports no estimator,
#: signal chain, simulator or metric, and none of those imports it.
IMPORT_CEILING = {"mmsnap_graph.io": 1}

#: Extra bans: (importing package, imported name prefix, reason).
FORBIDDEN = (
    ("mmsnap_graph.radar", "gtsam", "radar must not import GTSAM"),
    ("mmsnap_graph.radar", "factors.gtsam_factors", "radar must not import GTSAM"),
    ("mmsnap_graph.radar", "mmsnap_graph.tracking", "radar must not import tracking"),
)

HARD_RULES = (
    "function-length",
    "module-length",
    "layer-order",
    "package-cycle",
    "private-import",
    "model-count",
    "public-parameters",
    "folder-size",
    "history",
    "test-files",
)

#: Rules reported but not yet failing the exit code (a rule stays here only
#: while the tree is being brought to it; empty when every rule holds).
PENDING_RULES: frozenset[str] = frozenset()

MAX_PUBLIC_PARAMETERS = 10
MAX_FOLDER_MODULES = 12
#: Share of the library's modules that need a test file named after them.
MIN_TESTED_SHARE = 0.80
#: History narrated in the library ("issue 12", "Build 3"): comments say why, git says when.
HISTORY_PATTERN = re.compile(r"(?i)\b(issue|build)\s+#?\d+\b")


@dataclass(frozen=True)
class Violation:
    rule: str
    where: str
    message: str

    def __str__(self) -> str:
        return f"[{self.rule}] {self.where}: {self.message}"


@dataclass(frozen=True)
class Import:
    """One import statement's edge: ``source`` module imports ``target``."""

    source: str
    target: str
    line: int
    function_level: bool
    names: tuple[str, ...] = ()


@dataclass
class Report:
    violations: list[Violation] = field(default_factory=list)
    function_imports: list[Import] = field(default_factory=list)
    module_cycles: list[list[str]] = field(default_factory=list)
    model_definitions: list[str] = field(default_factory=list)
    model_wrappers: list[str] = field(default_factory=list)
    n_modules: int = 0
    untested: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not (self.broken_rules() - PENDING_RULES)

    def broken_rules(self) -> set[str]:
        return {v.rule for v in self.violations}

    def of_rule(self, rule: str) -> list[Violation]:
        return [v for v in self.violations if v.rule == rule]


# --------------------------------------------------------------------- scan


@dataclass
class _Module:
    name: str          # dotted, e.g. mmsnap_graph.fusion.solvers.gtsam_graph
    path: Path
    rel: str           # path relative to the root, for messages
    is_package: bool   # an __init__.py
    tree: ast.Module
    n_lines: int


def _scan(root: Path) -> dict[str, _Module]:
    modules: dict[str, _Module] = {}
    for top in TOP_PACKAGES:
        base = root / top
        if not base.is_dir():
            continue
        for path in sorted(base.rglob("*.py")):
            rel = path.relative_to(root)
            if any(part.startswith(".") or part == "__pycache__" for part in rel.parts):
                continue
            parts = list(rel.with_suffix("").parts)
            is_package = parts[-1] == "__init__"
            if is_package:
                parts = parts[:-1]
            text = path.read_text(encoding="utf-8")
            name = ".".join(parts)
            modules[name] = _Module(name, path, rel.as_posix(), is_package,
                                    ast.parse(text, filename=str(rel)), len(text.splitlines()))
    return modules


def _package_of(module: str) -> str:
    """The layer unit a module belongs to (a key of LAYERS)."""
    parts = module.split(".")
    if parts[0] == "factors":
        return "factors"
    if len(parts) == 1 or parts[1] == "__main__":
        return "mmsnap_graph"  # the package facade and its ``python -m`` entry point
    second = parts[1]
    if second.startswith("_"):
        return f"mmsnap_graph.{second}"  # a private helper module: layer 1
    return f"mmsnap_graph.{second}"


def _layer(package: str) -> float | None:
    if package in LAYERS:
        return LAYERS[package]
    if package.startswith("mmsnap_graph._"):
        return 1
    return None


def _resolve_base(module: _Module, level: int, target: str | None) -> str:
    if level == 0:
        return target or ""
    pkg = module.name if module.is_package else module.name.rpartition(".")[0]
    parts = pkg.split(".")
    if level > 1:
        parts = parts[: len(parts) - (level - 1)]
    base = ".".join(parts)
    return f"{base}.{target}" if target else base


def _project_module(name: str, modules: dict[str, _Module]) -> str | None:
    """The longest prefix of ``name`` that is a project module, if any."""
    parts = name.split(".")
    while parts:
        candidate = ".".join(parts)
        if candidate in modules:
            return candidate
        parts.pop()
    return None


class _ImportVisitor(ast.NodeVisitor):
    def __init__(self, module: _Module) -> None:
        self.module = module
        self.depth = 0
        self.found: list[tuple[str, int, bool, tuple[str, ...]]] = []

    def _function(self, node) -> None:
        self.depth += 1
        self.generic_visit(node)
        self.depth -= 1

    visit_FunctionDef = visit_AsyncFunctionDef = visit_Lambda = _function

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            self.found.append((alias.name, node.lineno, self.depth > 0, ()))

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        base = _resolve_base(self.module, node.level, node.module)
        names = tuple(a.name for a in node.names)
        self.found.append((base, node.lineno, self.depth > 0, names))


def _imports(module: _Module, modules: dict[str, _Module]) -> tuple[list[Import], list[tuple]]:
    """Project-internal import edges, and the external imports (name, line)."""
    visitor = _ImportVisitor(module)
    visitor.visit(module.tree)
    edges: list[Import] = []
    external: list[tuple] = []
    for base, line, in_function, names in visitor.found:
        if _project_module(base, modules) is None:
            external.append((base, line))
            continue
        if not names:
            edges.append(Import(module.name, _project_module(base, modules), line, in_function))
            continue
        # from base import a, b: a submodule counts as its own target
        plain = []
        for n in names:
            sub = f"{base}.{n}"
            if sub in modules:
                edges.append(Import(module.name, sub, line, in_function))
            else:
                plain.append(n)
        if plain:
            edges.append(Import(module.name, _project_module(base, modules), line, in_function,
                                tuple(plain)))
    return edges, external


# -------------------------------------------------------------------- rules


def _check_lengths(modules: dict[str, _Module], report: Report) -> None:
    for m in modules.values():
        if m.n_lines > MAX_MODULE_LINES:
            report.violations.append(Violation(
                "module-length", m.rel, f"{m.n_lines} lines > {MAX_MODULE_LINES}"))
        for node in ast.walk(m.tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    report.violations.append(Violation(
                        "function-length", f"{m.rel}:{node.lineno}",
                        f"{node.name} has {n} lines > {MAX_FUNCTION_LINES}"))


def _check_layers(m: _Module, edges: list[Import], external: list[tuple], report: Report) -> None:
    src_pkg = _package_of(m.name)
    src_layer = _layer(src_pkg)
    if src_layer is None:
        report.violations.append(Violation(
            "layer-order", m.rel, f"{m.name} is in no layer (known: {', '.join(LAYERS)})"))
        return
    for e in edges:
        dst_pkg = _package_of(e.target)
        dst_layer = _layer(dst_pkg)
        if dst_pkg == src_pkg or dst_layer is None:
            continue
        if dst_layer > src_layer:
            report.violations.append(Violation(
                "layer-order", f"{m.rel}:{e.line}",
                f"{LAYER_NAMES[src_layer]} module {m.name} imports {e.target} "
                f"({LAYER_NAMES[dst_layer]}, a higher layer)"))
        elif dst_layer > IMPORT_CEILING.get(src_pkg, dst_layer):
            report.violations.append(Violation(
                "layer-order", f"{m.rel}:{e.line}",
                f"{LAYER_NAMES[src_layer]} module {m.name} imports {e.target} "
                f"({LAYER_NAMES[dst_layer]}): {src_pkg} imports only up to the "
                f"{LAYER_NAMES[IMPORT_CEILING[src_pkg]]} layer"))
    targets = [(e.target, e.line) for e in edges] + external
    for pkg, banned, reason in FORBIDDEN:
        if src_pkg != pkg:
            continue
        for name, line in targets:
            if name == banned or name.startswith(banned + "."):
                report.violations.append(Violation(
                    "layer-order", f"{m.rel}:{line}", f"{reason} ({m.name} imports {name})"))


def _defined_names(m: _Module) -> set[str]:
    out = set()
    for node in m.tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for t in targets:
                out.update(n.id for n in ast.walk(t) if isinstance(n, ast.Name))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            out.update((a.asname or a.name).split(".")[0] for a in node.names)
    return out


def _check_private(m: _Module, edges: list[Import], modules: dict[str, _Module],
                   report: Report) -> None:
    for e in edges:
        if e.target == m.name:
            continue
        for n in e.names:
            if n.startswith("_") and not n.startswith("__") and f"{e.target}.{n}" not in modules:
                report.violations.append(Violation(
                    "private-import", f"{m.rel}:{e.line}",
                    f"{m.name} imports the private name {n} from {e.target}"))


def _strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm, iterative; components of more than one node, sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return sorted(out)


def _check_cycles(all_edges: list[Import], report: Report) -> None:
    pkg_graph: dict[str, set[str]] = {}
    witness: dict[tuple[str, str], Import] = {}
    mod_graph: dict[str, set[str]] = {}
    for e in all_edges:
        a, b = _package_of(e.source), _package_of(e.target)
        if a != b:
            pkg_graph.setdefault(a, set()).add(b)
            witness.setdefault((a, b), e)
        elif e.source != e.target:
            mod_graph.setdefault(e.source, set()).add(e.target)
    for comp in _strongly_connected(pkg_graph):
        links = []
        for a in comp:
            for b in sorted(pkg_graph.get(a, ())):
                if b in comp:
                    w = witness[(a, b)]
                    links.append(f"{w.source} -> {w.target} (line {w.line})")
        report.violations.append(Violation(
            "package-cycle", " <-> ".join(comp), "; ".join(links)))
    report.module_cycles = _strongly_connected(mod_graph)


def _called_names(node: ast.AST) -> set[str]:
    out = set()
    for call in ast.walk(node):
        if isinstance(call, ast.Call):
            f = call.func
            if isinstance(f, ast.Name):
                out.add(f.id)
            elif isinstance(f, ast.Attribute):
                out.add(f.attr)
    return out


def _check_models(modules: dict[str, _Module], report: Report) -> None:
    """A function named like the model counts as a definition, unless it
    calls another such function of ``factors/`` (then it is a wrapper derived
    from that one, e.g. a form that adds the pose Jacobian to the vector
    form); aliases of imported names are followed."""
    found = []  # (where, name, node, aliases of the module)
    for m in modules.values():
        if _package_of(m.name) != "factors":
            continue
        aliases = {a.asname: a.name for n in ast.walk(m.tree) if isinstance(n, ast.ImportFrom)
                   for a in n.names if a.asname}
        for node in ast.walk(m.tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and \
                    MODEL_NAME_PATTERN.match(node.name.lstrip("_")):
                found.append((f"{m.rel}:{node.lineno}", node.name, node, aliases))
    model_names = {name for _, name, _, _ in found}
    for where, name, node, aliases in found:
        calls = {aliases.get(c, c) for c in _called_names(node)} - {name}
        if calls & model_names:
            report.model_wrappers.append(
                f"{where} {name} (calls {', '.join(sorted(calls & model_names))})")
        else:
            report.model_definitions.append(f"{where} {name}")
    n = len(report.model_definitions)
    if n > MAX_MODEL_DEFINITIONS:
        report.violations.append(Violation(
            "model-count", "factors/",
            f"{n} definitions of the measurement model > {MAX_MODEL_DEFINITIONS}: "
            + ", ".join(d.split(" ")[-1] for d in report.model_definitions)))


def _check_parameters(modules: dict[str, _Module], report: Report) -> None:
    """No public function or method with more than MAX_PUBLIC_PARAMETERS
    parameters (``self``/``cls`` not counted): wide entry points take an
    options object."""
    for m in modules.values():
        for node in ast.walk(m.tree):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) or \
                    node.name.startswith("_"):
                continue
            a = node.args
            names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
            n = len([x for x in names if x not in ("self", "cls")])
            if n > MAX_PUBLIC_PARAMETERS:
                report.violations.append(Violation(
                    "public-parameters", f"{m.rel}:{node.lineno}",
                    f"{node.name} takes {n} parameters > {MAX_PUBLIC_PARAMETERS} "
                    "(use an options object)"))


def _check_folders(modules: dict[str, _Module], report: Report) -> None:
    """No package folder with more than MAX_FOLDER_MODULES modules directly
    inside (``__init__`` and ``__main__`` not counted)."""
    count: dict[str, int] = {}
    for m in modules.values():
        if m.is_package or m.path.name == "__main__.py":
            continue
        folder = str(Path(m.rel).parent.as_posix())
        count[folder] = count.get(folder, 0) + 1
    for folder, n in sorted(count.items()):
        if n > MAX_FOLDER_MODULES:
            report.violations.append(Violation(
                "folder-size", folder, f"{n} modules directly inside > {MAX_FOLDER_MODULES} "
                "(group them by stage in subfolders)"))


def _check_history(modules: dict[str, _Module], report: Report) -> None:
    for m in modules.values():
        for i, line in enumerate(m.path.read_text(encoding="utf-8").splitlines(), 1):
            found = HISTORY_PATTERN.search(line)
            if found:
                report.violations.append(Violation(
                    "history", f"{m.rel}:{i}", f"{found.group(0)!r}: comments say why, not when"))


def test_file_of(rel: str) -> str:
    """The test file a library module's tests live in: the tests tree mirrors
    the packages (``mmsnap_graph/calibration/joint/presolve.py`` ->
    ``tests/calibration/joint/test_presolve.py``; ``factors/models.py`` ->
    ``tests/factors/test_models.py``)."""
    parts = Path(rel).parts
    folder = parts[1:-1] if parts[0] == "mmsnap_graph" else parts[:-1]
    return Path("tests", *folder, f"test_{Path(rel).stem}.py").as_posix()


def _has_assertion(path: Path) -> bool:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Assert):
            return True
        if isinstance(node, ast.Attribute) and node.attr in ("raises", "warns") or \
                isinstance(node, ast.Name) and node.id.startswith("assert_") or \
                isinstance(node, ast.Attribute) and node.attr.startswith("assert_"):
            return True
    return False


def _check_test_files(root: Path, modules: dict[str, _Module], report: Report) -> None:
    """At least MIN_TESTED_SHARE of the library's modules have a test file
    named after them (:func:`test_file_of`) that asserts something."""
    if not (root / "tests").is_dir():
        return
    library = [m for m in modules.values()
               if not m.is_package and m.path.name != "__main__.py"]
    missing = [m.rel for m in library if not (root / test_file_of(m.rel)).is_file()]
    for m in library:
        test = root / test_file_of(m.rel)
        if test.is_file() and not _has_assertion(test):
            report.violations.append(Violation(
                "test-files", test_file_of(m.rel), "asserts nothing (a test that cannot fail)"))
    report.untested = sorted(missing)
    share = 1.0 - len(missing) / max(len(library), 1)
    if share < MIN_TESTED_SHARE:
        report.violations.append(Violation(
            "test-files", "tests/", f"{len(library) - len(missing)} of {len(library)} modules "
            f"({share:.0%}) have a test file named after them < {MIN_TESTED_SHARE:.0%}"))


def check(root: str | Path) -> Report:
    """Check every rule on the tree at ``root`` (which holds factors/ and mmsnap_graph/)."""
    root = Path(root)
    modules = _scan(root)
    report = Report(n_modules=len(modules))
    _check_lengths(modules, report)
    all_edges: list[Import] = []
    for m in modules.values():
        edges, external = _imports(m, modules)
        all_edges += edges
        _check_layers(m, edges, external, report)
        _check_private(m, edges, modules, report)
        report.function_imports += [e for e in edges if e.function_level]
    _check_cycles(all_edges, report)
    _check_models(modules, report)
    _check_parameters(modules, report)
    _check_folders(modules, report)
    _check_history(modules, report)
    _check_test_files(root, modules, report)
    return report


# ---------------------------------------------------------------------- CLI


def format_report(report: Report, verbose: bool = True) -> str:
    lines = [f"checked {report.n_modules} modules"]
    for rule in HARD_RULES:
        found = report.of_rule(rule)
        pending = " (pending: not yet enforced)" if rule in PENDING_RULES and found else ""
        lines.append(f"{rule}: {'ok' if not found else f'{len(found)} violation(s)'}{pending}")
        lines += [f"  {v.where}: {v.message}" for v in found]
    if verbose and report.untested:
        lines.append(f"modules without a test file named after them: {len(report.untested)}")
        lines += [f"  {rel}" for rel in report.untested]
    lines.append(f"measurement-model definitions in factors/: {len(report.model_definitions)} "
                 f"(at most {MAX_MODEL_DEFINITIONS})")
    if verbose:
        lines += [f"  {d}" for d in report.model_definitions]
        lines += [f"  (wrapper) {d}" for d in report.model_wrappers]
    lines.append(f"function-level imports of project modules: {len(report.function_imports)} "
                 "(allowed only to keep gtsam/sklearn/matplotlib/h5py off a light path)")
    if verbose:
        lines += [f"  {e.source}:{e.line} -> {e.target}" for e in report.function_imports]
    lines.append(f"import cycles between modules of one package: {len(report.module_cycles)}")
    lines += [f"  {' <-> '.join(c)}" for c in report.module_cycles]
    failed = report.broken_rules() - PENDING_RULES
    lines.append("OK" if report.ok else
                 f"FAILED: {', '.join(r for r in HARD_RULES if r in failed)}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1],
                        help="tree holding factors/ and mmsnap_graph/ (default: this repository)")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="counts only, no lists of function-level imports")
    args = parser.parse_args(argv)
    report = check(args.root)
    print(format_report(report, verbose=not args.quiet))
    return 0 if report.ok else 1


if __name__ == "__main__":
    sys.exit(main())
