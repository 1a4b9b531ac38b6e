"""The redesign's structure rules (tools/check_structure.py), on the repository
and on small synthetic trees that show each rule is detected."""

import ast
import importlib.util
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("check_structure", ROOT / "tools" / "check_structure.py")
cs = importlib.util.module_from_spec(_spec)
sys.modules["check_structure"] = cs  # dataclasses look their module up by name
_spec.loader.exec_module(cs)

# Rules still broken on main at the time of writing while other branches fix
# them; the lead removes an entry once the fix is merged.
STILL_BROKEN_ON_MAIN: dict[str, str] = {
    rule: "the reorganisation that brings the tree to this rule is under way"
    for rule in cs.PENDING_RULES}


@pytest.fixture(scope="module")
def repo_report():
    return cs.check(ROOT)


@pytest.mark.parametrize("rule", [
    pytest.param(rule, marks=pytest.mark.xfail(strict=False, reason=STILL_BROKEN_ON_MAIN[rule]))
    if rule in STILL_BROKEN_ON_MAIN else rule
    for rule in cs.HARD_RULES
])
def test_repository_keeps_the_rule(repo_report, rule):
    found = repo_report.of_rule(rule)
    assert not found, "\n".join(map(str, found))


def test_repository_scan_sees_both_packages(repo_report):
    # A scan that found nothing would pass every rule.
    assert repo_report.n_modules >= 40
    assert any(d.startswith("factors/models.py") for d in repo_report.model_definitions)


def test_script_exit_code_follows_the_hard_rules(tmp_path):
    _tree(tmp_path, {"factors/models.py": "def measurement_model(x, p):\n    return x\n"})
    script = ROOT / "tools" / "check_structure.py"
    ok = subprocess.run([sys.executable, str(script), "--root", str(tmp_path)],
                        capture_output=True, text=True)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert "OK" in ok.stdout
    _tree(tmp_path, {"mmsnap_graph/data/x.py": "from ..fusion import y\n",
                     "mmsnap_graph/fusion/y.py": ""})
    bad = subprocess.run([sys.executable, str(script), "--root", str(tmp_path)],
                         capture_output=True, text=True)
    assert bad.returncode == 1
    assert "layer-order" in bad.stdout and "FAILED" in bad.stdout


# ------------------------------------------------------- synthetic trees


def _tree(root: Path, files: dict[str, str]) -> Path:
    """Write a package tree; every folder gets an __init__.py."""
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    for top in ("factors", "mmsnap_graph"):
        for folder in [root / top, *(p for p in (root / top).rglob("*") if p.is_dir())]:
            if folder.exists() and not (folder / "__init__.py").exists():
                (folder / "__init__.py").write_text("")
    return root


def _rules(root: Path) -> set[str]:
    return cs.check(root).broken_rules()


def test_a_clean_layered_tree_passes(tmp_path):
    _tree(tmp_path, {
        "factors/models.py": "import math\n\ndef measurement_model(s, p):\n    return s\n",
        "mmsnap_graph/errors.py": "class MmsnapError(Exception):\n    pass\n",
        "mmsnap_graph/_validation.py": "from .errors import MmsnapError\n\ndef check(x):\n    return x\n",
        "mmsnap_graph/data/recording.py": "from factors.models import measurement_model\n"
                                          "from .._validation import check\n",
        "mmsnap_graph/fusion/oneshot.py": "from ..data.recording import measurement_model\n",
        "mmsnap_graph/tracking/ekf.py": "from ..fusion import oneshot\n",
        "mmsnap_graph/radar/chain.py": "import numpy\nfrom ..data import recording\n",
        "mmsnap_graph/io/hdf5.py": "from ..data.recording import measurement_model\n",
        "mmsnap_graph/app/cli.py": "from ..io import hdf5\n\ndef main():\n"
                                   "    from ..tracking import ekf  # lazy\n    return ekf\n",
    })
    report = cs.check(tmp_path)
    assert report.ok, cs.format_report(report)
    assert [(e.source, e.target) for e in report.function_imports] == [
        ("mmsnap_graph.app.cli", "mmsnap_graph.tracking.ekf")]


def test_long_function_is_detected(tmp_path):
    body = "".join(f"    x{i} = {i}\n" for i in range(99))  # def line + 99 = 100 lines
    _tree(tmp_path, {"mmsnap_graph/fusion/a.py": f"def fine():\n{body}"})
    assert "function-length" not in _rules(tmp_path)
    _tree(tmp_path, {"mmsnap_graph/fusion/a.py": f"def fine():\n{body}    x = 1\n"})
    report = cs.check(tmp_path)
    assert [v.message for v in report.of_rule("function-length")] == ["fine has 101 lines > 100"]


def test_long_method_is_detected(tmp_path):
    body = "".join(f"        x{i} = {i}\n" for i in range(120))
    _tree(tmp_path, {"mmsnap_graph/fusion/a.py": f"class A:\n    def step(self):\n{body}"})
    assert "function-length" in _rules(tmp_path)


def test_long_module_is_detected(tmp_path):
    _tree(tmp_path, {"mmsnap_graph/sim/a.py": "x = 1\n" * 650})
    assert "module-length" not in _rules(tmp_path)
    _tree(tmp_path, {"mmsnap_graph/sim/a.py": "x = 1\n" * 651})
    assert "module-length" in _rules(tmp_path)


@pytest.mark.parametrize("importer, statement", [
    ("factors/models.py", "import mmsnap_graph.data.recording\n"),
    ("factors/models.py", "from mmsnap_graph import errors\n"),
    ("mmsnap_graph/data/recording.py", "from ..fusion import oneshot\n"),
    ("mmsnap_graph/_validation.py", "from .fusion.oneshot import solve\n"),
    ("mmsnap_graph/errors.py", "from .io import hdf5\n"),
    ("mmsnap_graph/fusion/oneshot.py", "from mmsnap_graph.io.hdf5 import write\n"),
    ("mmsnap_graph/calibration/network.py", "def f():\n    from ..io import hdf5\n"),
    ("mmsnap_graph/io/hdf5.py", "from ..app import cli\n"),
    ("mmsnap_graph/sim/cube.py", "from .. import solve\n"),
    ("mmsnap_graph/radar/chain.py", "import gtsam\n"),
    ("mmsnap_graph/radar/chain.py", "def f():\n    from gtsam import Pose2\n"),
    ("mmsnap_graph/radar/chain.py", "from factors.gtsam_factors import measurement_noise\n"),
    ("mmsnap_graph/radar/chain.py", "from ..tracking.ekf import LocalTracker\n"),
])
def test_import_against_the_layers_is_detected(tmp_path, importer, statement):
    files = {
        "factors/models.py": "", "factors/gtsam_factors.py": "import gtsam\n",
        "mmsnap_graph/errors.py": "", "mmsnap_graph/_validation.py": "",
        "mmsnap_graph/data/recording.py": "", "mmsnap_graph/fusion/oneshot.py": "",
        "mmsnap_graph/calibration/network.py": "", "mmsnap_graph/tracking/ekf.py": "",
        "mmsnap_graph/radar/chain.py": "", "mmsnap_graph/sim/cube.py": "",
        "mmsnap_graph/io/hdf5.py": "", "mmsnap_graph/app/cli.py": "",
    }
    _tree(tmp_path, files)
    assert cs.check(tmp_path).ok
    _tree(tmp_path, {importer: statement})
    report = cs.check(tmp_path)
    assert report.broken_rules() == {"layer-order"}, cs.format_report(report)


@pytest.mark.parametrize("importer, statement, ok", [
    ("mmsnap_graph/evaluation/metrics.py", "from factors.models import wrap_angle\n", True),
    ("mmsnap_graph/evaluation/metrics.py", "from ..data.recording import Truth\n", True),
    ("mmsnap_graph/evaluation/metrics.py", "from .._validation import check\n", True),
    ("mmsnap_graph/fusion/oneshot.py", "from ..evaluation.metrics import nees\n", True),
    ("mmsnap_graph/app/cli.py", "from ..evaluation import nees\n", True),
    ("mmsnap_graph/evaluation/metrics.py", "from ..fusion.oneshot import solve\n", False),
    ("mmsnap_graph/evaluation/metrics.py", "from ..tracking import ekf\n", False),
    ("mmsnap_graph/evaluation/metrics.py", "from ..app import cli\n", False),
    ("mmsnap_graph/data/recording.py", "from ..evaluation import nees\n", False),
    ("mmsnap_graph/_validation.py", "from .evaluation.metrics import nees\n", False),
])
def test_metrics_sit_between_the_data_and_the_estimators(tmp_path, importer, statement, ok):
    _tree(tmp_path, {
        "factors/models.py": "", "mmsnap_graph/errors.py": "", "mmsnap_graph/_validation.py": "",
        "mmsnap_graph/data/recording.py": "", "mmsnap_graph/evaluation/metrics.py": "",
        "mmsnap_graph/fusion/oneshot.py": "", "mmsnap_graph/tracking/ekf.py": "",
        "mmsnap_graph/app/cli.py": "",
    })
    assert cs.check(tmp_path).ok
    _tree(tmp_path, {importer: statement})
    report = cs.check(tmp_path)
    assert report.ok == ok, cs.format_report(report)
    if not ok:
        assert report.broken_rules() == {"layer-order"}


@pytest.mark.parametrize("statement, ok", [
    ("from ..data.calibration import RecordingCalibration\n", True),
    ("from .._atomic import atomic_write\n", True),
    ("from ..errors import FileFormatError\n", True),
    ("from factors.models import wrap_angle\n", True),
    ("from ..calibration.network import calibrate_recording\n", False),
    ("from mmsnap_graph.calibration import network\n", False),
    ("def f():\n    from ..fusion.oneshot import solve\n", False),
    ("from ..tracking import ekf\n", False),
    ("from ..radar.chain import run\n", False),
    ("from ..sim import cube\n", False),
    ("from ..evaluation.metrics import nees\n", False),
])
def test_io_sits_below_the_estimators(tmp_path, statement, ok):
    # io reads and writes the data layer's records: it imports no estimator
    # (nor signal chain, simulator, metric), though the layer table puts it above them.
    _tree(tmp_path, {
        "factors/models.py": "", "mmsnap_graph/errors.py": "", "mmsnap_graph/_atomic.py": "",
        "mmsnap_graph/data/calibration.py": "", "mmsnap_graph/evaluation/metrics.py": "",
        "mmsnap_graph/calibration/network.py": "", "mmsnap_graph/fusion/oneshot.py": "",
        "mmsnap_graph/tracking/ekf.py": "", "mmsnap_graph/radar/chain.py": "",
        "mmsnap_graph/sim/cube.py": "", "mmsnap_graph/io/hdf5.py": "",
        "mmsnap_graph/app/cli.py": "from ..io import hdf5\nfrom ..calibration import network\n",
    })
    assert cs.check(tmp_path).ok
    _tree(tmp_path, {"mmsnap_graph/io/calibration.py": statement})
    report = cs.check(tmp_path)
    assert report.ok == ok, cs.format_report(report)
    if not ok:
        assert report.broken_rules() == {"layer-order"}
        assert "imports only up to the data layer" in cs.format_report(report)


def test_module_outside_every_layer_is_detected(tmp_path):
    _tree(tmp_path, {"mmsnap_graph/misc/helpers.py": "x = 1\n"})
    assert "layer-order" in _rules(tmp_path)


def test_peers_may_import_each_other_one_way(tmp_path):
    _tree(tmp_path, {
        "mmsnap_graph/tracking/ekf.py": "from ..fusion.oneshot import fuse\n",
        "mmsnap_graph/fusion/oneshot.py": "def fuse():\n    pass\n",
    })
    assert cs.check(tmp_path).ok


def test_package_cycle_is_detected_even_through_a_function_level_import(tmp_path):
    _tree(tmp_path, {
        "mmsnap_graph/tracking/ekf.py": "from ..fusion.oneshot import fuse\n",
        "mmsnap_graph/fusion/oneshot.py": "def fuse():\n    from ..tracking import ekf\n",
    })
    report = cs.check(tmp_path)
    assert report.broken_rules() == {"package-cycle"}
    assert report.of_rule("package-cycle")[0].where == \
        "mmsnap_graph.fusion <-> mmsnap_graph.tracking"


def test_round_about_package_cycle_is_detected(tmp_path):
    _tree(tmp_path, {
        "mmsnap_graph/sim/a.py": "from ..calibration import b\n",
        "mmsnap_graph/calibration/b.py": "from ..fusion import c\n",
        "mmsnap_graph/fusion/c.py": "from ..sim import a\n",
    })
    cycles = cs.check(tmp_path).of_rule("package-cycle")
    assert len(cycles) == 1
    assert cycles[0].where.count("<->") == 2


def test_module_cycle_inside_a_package_is_reported_not_enforced(tmp_path):
    _tree(tmp_path, {
        "mmsnap_graph/fusion/grid.py": "from .oneshot import fuse\n",
        "mmsnap_graph/fusion/oneshot.py": "def fuse():\n    from .grid import g\n",
    })
    report = cs.check(tmp_path)
    assert report.ok
    assert report.module_cycles == [["mmsnap_graph.fusion.grid", "mmsnap_graph.fusion.oneshot"]]


@pytest.mark.parametrize("statement", [
    "from .oneshot import _check_poses\n",
    "from mmsnap_graph.fusion.oneshot import fuse, _check_poses\n",
    "from ..tracking.ekf import _sym as sym\n",
    "def f():\n    from .oneshot import _check_poses\n",
])
def test_private_name_across_modules_is_detected(tmp_path, statement):
    _tree(tmp_path, {
        "mmsnap_graph/fusion/oneshot.py": "def fuse():\n    pass\n\ndef _check_poses():\n    pass\n",
        "mmsnap_graph/tracking/ekf.py": "def _sym(p):\n    return p\n",
        "mmsnap_graph/fusion/bounds.py": statement,
    })
    report = cs.check(tmp_path)
    assert report.broken_rules() == {"private-import"}, cs.format_report(report)


def test_private_helper_modules_and_private_aliases_are_fine(tmp_path):
    _tree(tmp_path, {
        "mmsnap_graph/_linalg.py": "def chol_soa(a):\n    return a\n",
        "mmsnap_graph/fusion/batch.py": "from .._linalg import chol_soa\n"
                                        "from .. import _linalg\n"
                                        "from factors.models import measurement_model as _model\n",
        "factors/models.py": "def measurement_model(s, p):\n    return s\n",
    })
    assert cs.check(tmp_path).ok


def test_too_many_measurement_models_are_detected(tmp_path):
    three = ("def measurement_model(s, p):\n    pass\n\n"
             "def measurement_model_pose(p, s):\n    pass\n\n"
             "def _measurement_kernel(x, y):\n    pass\n\n"
             "def wrap_angle(a):\n    pass\n")
    _tree(tmp_path, {"factors/models.py": three})
    report = cs.check(tmp_path)
    assert report.ok and len(report.model_definitions) == 3
    _tree(tmp_path, {"factors/gtsam_factors.py": "def range_model(s, p):\n    pass\n"})
    report = cs.check(tmp_path)
    assert report.broken_rules() == {"model-count"}
    assert "range_model" in report.of_rule("model-count")[0].message


def test_wrappers_of_the_model_are_listed_not_counted(tmp_path):
    _tree(tmp_path, {
        "factors/models.py": (
            "def _predict(s, p):\n    return s\n\n"
            "def measurement_model(s, p):\n    return _predict(s, p)\n\n"
            "def predict_measurements(s, p):\n    return _predict(s, p)[0]\n\n"
            "def measurement_model_pose(p, s):\n    return measurement_model(s, p)\n\n"
            "def measurement_model_scalar(x, y):\n    return x\n"),
        "factors/gtsam_factors.py": (
            "from .models import measurement_model_scalar as _kernel_alias\n\n"
            "def _measurement_kernel(x):\n    return _kernel_alias(x, x)\n"),
    })
    report = cs.check(tmp_path)
    assert report.ok, cs.format_report(report)
    assert [d.split()[-1] for d in report.model_definitions] == [
        "_predict", "measurement_model_scalar"]
    assert len(report.model_wrappers) == 4
    # a fourth function that computes the model itself breaks the rule
    _tree(tmp_path, {"factors/extra.py": "def range_model(s, p):\n    return abs(s - p)\n",
                     "factors/more.py": "def omega_model(s, p):\n    return s\n"})
    assert cs.check(tmp_path).broken_rules() == {"model-count"}


@pytest.mark.parametrize("name", [
    "range_model", "omega_model", "doppler_model", "measurement_model", "measurement_model_pose",
    "measurement_model_scalar", "_measurement_model_scalar", "predict_measurements",
    "_measurement_kernel", "model_scalar", "_measurement_scalar", "_scalar_kernel",
    "predict_measurement", "measurements_from_state",
])
def test_model_name_pattern_catches_the_known_variants(name):
    assert cs.MODEL_NAME_PATTERN.match(name.lstrip("_"))


@pytest.mark.parametrize("name", [
    "wrap_angle", "wrap_angle_scalar", "detection_to_local", "detection_to_global", "residual",
    "local_to_global", "global_to_local", "node_measurement_factor", "frame_measurement_factor",
    "pose_measurement_factor", "scalar_measurement_factor", "measurement_noise", "_node_error",
    "_pose_error", "constant_velocity_factor", "cv_transition", "cv_process_noise",
    "constant_velocity_model", "state_prior_factor", "MEASUREMENT_NAMES",
])
def test_model_name_pattern_leaves_other_functions(name):
    assert not cs.MODEL_NAME_PATTERN.match(name)


# ------------------------------------------------------- the tests themselves

#: The package's own top-level packages (a test's use of their private names is checked).
PACKAGES = ("mmsnap_graph", "factors")

#: Private names of the package that tests still use, (test file, name) -> why.
#: No public function computes the same thing; remove an entry when one does.
PRIVATE_USES_ALLOWED: dict[tuple[str, str], str] = {
    ("fusion/solvers/test_gtsam_graph.py", "_model_scalar"):
        "fault injection: monkeypatching the factor callback's kernel makes it raise inside GTSAM",
    ("calibration/joint/test_presolve.py", "_problem"):
        "the range offset's gradient against a finite difference of the pre-solve's own cost, "
        "which no public function returns",
    ("fusion/recording/test_walls.py", "_lines"):
        "the line search's updated counts against a reference that counts each line again; "
        "learn_walls returns walls, not the lines, their proposals and images compared",
    ("calibration/noise/test_tails.py", "_loo_residuals"):
        "the leave-one-out fits, solved together, against each row's own least-squares fit; "
        "tail_variances returns only the excess variances they lead to",
    ("fusion/recording/test_walls.py", "_LineIndex"):
        "the per-node counts taken from the index of all the proposals, as learn_walls does, "
        "against the reference counted from each node's proposals alone",
}


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _private_uses(source: str) -> set[str]:
    """Private names of the package a test module uses: imported by name, taken
    as ``module._name`` from an imported package module, or handed to
    ``monkeypatch.setattr``/``getattr`` as a string. Public names of the
    private helper modules (``mmsnap_graph._linalg`` ...) are not private uses,
    as in the package's own rule."""
    tree = ast.parse(source)
    modules: set[str] = set()  # local names bound to a package module
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] in PACKAGES:
                    modules.add(alias.asname or alias.name.split(".")[0])
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in PACKAGES:
            for alias in node.names:
                if _is_private(alias.name) and not _is_helper_module(node.module, alias.name):
                    found.add(alias.name)
                modules.add(alias.asname or alias.name)  # may be a module; harmless if not
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _is_private(node.attr):
            base = node.value
            while isinstance(base, ast.Attribute):
                base = base.value
            if isinstance(base, ast.Name) and base.id in modules:
                found.add(node.attr)
        elif isinstance(node, ast.Call) and isinstance(node.func, (ast.Attribute, ast.Name)) \
                and getattr(node.func, "attr", getattr(node.func, "id", "")) in ("setattr", "getattr"):
            names = [a.value for a in node.args[1:2]
                     if isinstance(a, ast.Constant) and isinstance(a.value, str)]
            found.update(n for n in names if _is_private(n))
    return found


def _is_helper_module(module: str, name: str) -> bool:
    """``from mmsnap_graph import _linalg``: a private helper module, allowed."""
    return (ROOT / Path(*module.split(".")) / f"{name}.py").is_file()


def _test_modules() -> list[Path]:
    return sorted((ROOT / "tests").rglob("*.py"))


def test_tests_use_no_private_name_of_the_package():
    used = {(p.relative_to(ROOT / "tests").as_posix(), n) for p in _test_modules()
            for n in _private_uses(p.read_text())}
    unexpected = sorted(used - set(PRIVATE_USES_ALLOWED))
    assert not unexpected, f"tests use private names (use the public function): {unexpected}"
    stale = sorted(set(PRIVATE_USES_ALLOWED) - used)
    assert not stale, f"PRIVATE_USES_ALLOWED lists uses that are gone; remove them: {stale}"


@pytest.mark.parametrize("source, expected", [
    ("from mmsnap_graph.fusion.batch import _evaluate\n", {"_evaluate"}),
    ("from mmsnap_graph.fusion import batch\nbatch._solve(1)\n", {"_solve"}),
    ("import mmsnap_graph.fusion.oneshot as oneshot\noneshot._x.y\n", {"_x"}),
    ("import factors.gtsam_factors as gf\ndef t(monkeypatch):\n"
     "    monkeypatch.setattr(gf, '_model_scalar', None)\n", {"_model_scalar"}),
    ("from mmsnap_graph._atomic import atomic_path\nfrom mmsnap_graph import _linalg\n", set()),
    ("class A:\n    def f(self):\n        return self._x\n", set()),
    ("from mmsnap_graph.fusion import batch\nbatch.__name__\n", set()),
])
def test_private_use_scan_sees_each_form(source, expected):
    assert _private_uses(source) == expected


def test_nested_packages_resolve_relative_imports(tmp_path):
    # A module two folders down: ``...`` leaves the sub-package and the package.
    _tree(tmp_path, {
        "mmsnap_graph/errors.py": "",
        "mmsnap_graph/fusion/problem.py": "def _hidden():\n    pass\n",
        "mmsnap_graph/fusion/solvers/scalar.py": "from ...errors import *\nfrom ..problem import *\n",
    })
    report = cs.check(tmp_path)
    assert report.ok, cs.format_report(report)
    assert {(e.source, e.target) for e in cs._imports(
        cs._scan(tmp_path)["mmsnap_graph.fusion.solvers.scalar"], cs._scan(tmp_path))[0]} == {
        ("mmsnap_graph.fusion.solvers.scalar", "mmsnap_graph.errors"),
        ("mmsnap_graph.fusion.solvers.scalar", "mmsnap_graph.fusion.problem")}
    _tree(tmp_path, {"mmsnap_graph/fusion/solvers/scalar.py":
                     "from ...io import hdf5\nfrom ..problem import _hidden\n",
                     "mmsnap_graph/io/hdf5.py": ""})
    assert _rules(tmp_path) == {"layer-order", "private-import"}


# ------------------------------------------------- rules of the second step


def test_wide_public_function_is_detected(tmp_path):
    nine = ", ".join(f"a{i}" for i in range(9))
    _tree(tmp_path, {"mmsnap_graph/fusion/a.py":
                     f"def ok(self, {nine}, *, b):\n    pass\n\n"
                     f"def _private({nine}, b, c, d):\n    pass\n"})
    assert "public-parameters" not in _rules(tmp_path)
    _tree(tmp_path, {"mmsnap_graph/fusion/a.py": f"def wide({nine}, *, b, c):\n    pass\n"})
    report = cs.check(tmp_path)
    assert [v.message for v in report.of_rule("public-parameters")] == [
        "wide takes 11 parameters > 10 (use an options object)"]


def test_crowded_folder_is_detected(tmp_path):
    _tree(tmp_path, {f"mmsnap_graph/sim/m{i}.py": "" for i in range(12)})
    assert "folder-size" not in _rules(tmp_path)
    _tree(tmp_path, {"mmsnap_graph/sim/m12.py": ""})
    assert [v.where for v in cs.check(tmp_path).of_rule("folder-size")] == ["mmsnap_graph/sim"]


@pytest.mark.parametrize("line, found", [
    ("# fixed in issue 12\n", True), ('"""Build 3 added it."""\n', True),
    ("# see Issue #7\n", True), ("# the issue is the clock\n", False),
    ("build_graph(3)\n", False)])
def test_history_in_the_library_is_detected(tmp_path, line, found):
    _tree(tmp_path, {"mmsnap_graph/sim/a.py": line})
    assert ("history" in _rules(tmp_path)) is found


def test_test_file_of_mirrors_the_packages():
    assert cs.test_file_of("mmsnap_graph/calibration/joint/presolve.py") == \
        "tests/calibration/joint/test_presolve.py"
    assert cs.test_file_of("factors/models.py") == "tests/factors/test_models.py"
    assert cs.test_file_of("mmsnap_graph/_atomic.py") == "tests/test__atomic.py"


def test_modules_without_test_files_are_counted(tmp_path):
    files = {f"mmsnap_graph/sim/m{i}.py": "" for i in range(5)}
    files.update({f"tests/sim/test_m{i}.py": "def test():\n    assert 1\n" for i in range(4)})
    _tree(tmp_path, files)
    report = cs.check(tmp_path)
    assert "test-files" not in report.broken_rules()          # 4 of 5 = 80 %
    assert report.untested == ["mmsnap_graph/sim/m4.py"]
    (tmp_path / "tests/sim/test_m3.py").unlink()
    assert "test-files" in _rules(tmp_path)                   # 3 of 5


def test_a_test_file_that_asserts_nothing_is_detected(tmp_path):
    _tree(tmp_path, {"mmsnap_graph/sim/m.py": "",
                     "tests/sim/test_m.py": "def test():\n    pass\n"})
    assert [v.message for v in cs.check(tmp_path).of_rule("test-files")] == [
        "asserts nothing (a test that cannot fail)"]
    for body in ("    with pytest.raises(ValueError):\n        f()\n",
                 "    np.testing.assert_allclose(1, 1)\n"):
        (tmp_path / "tests/sim/test_m.py").write_text(f"def test():\n{body}")
        assert "test-files" not in _rules(tmp_path)
