"""The package layout stays readable: no import cycles, no upward imports, no giant files or functions.

Data flows conf -> datagen -> dataset on disk -> hupbench -> models' predictions -> metrics, over a shared core:
``core`` imports none of the others; ``models`` and ``datagen`` import only the core (installed as
``hupbench.core``, ``hupbench.models`` and ``hupbench.datagen``: the folders keep their names, pyproject.toml maps
them); the inference path (``hupbench.inference.predict``) imports no torch and no generator module. Each subpackage's ``__init__``
docstring says what it may import; this test holds the rules that can be read from the code.
"""

import ast
from collections import defaultdict
from pathlib import Path

from helpers import REPO

PACKAGES = ("core", "datagen", "models", "hupbench")
#: folder -> the name it is installed and imported under (pyproject.toml's package-dir)
INSTALLED = {"core": "hupbench.core", "datagen": "hupbench.datagen", "models": "hupbench.models",
             "hupbench": "hupbench"}
#: package (folder) -> packages it must never import
FORBIDDEN = {"core": ("datagen", "models", "hupbench"), "datagen": ("models", "hupbench"),
             "models": ("datagen", "hupbench")}


def folder_of(name: str) -> str:
    """The package folder a module's installed name lives in: hupbench.core.io -> core, hupbench.cli -> hupbench."""
    parts = name.split(".")
    return parts[1] if parts[0] == "hupbench" and len(parts) > 1 and parts[1] in ("core", "datagen", "models") \
        else parts[0]


MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 100
#: the most parameters a function that runs a verb takes (more: a typed run or options object)
MAX_VERB_PARAMETERS = 8


def project_modules() -> dict[str, Path]:
    modules = {}
    for package in PACKAGES:
        for path in (REPO / package).rglob("*.py"):
            parts = path.relative_to(REPO).with_suffix("").parts
            parts = (*INSTALLED[package].split("."), *parts[1:])
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            modules[name] = path
    return modules


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Project modules ``name`` imports (at module level or inside functions)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([node.module] if node.module else []))
            targets = [base] + [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        for target in targets:
            # "from hupbench.core import keypoints" imports the module hupbench.core.keypoints, not the package
            if target in modules and target != name:
                found.add(target)
    return found


def import_graph() -> dict[str, set[str]]:
    modules = project_modules()
    graph = {name: imports_of(name, path, modules) for name, path in modules.items()}
    # importing a package's submodule runs the package's __init__: not an edge of interest
    return {name: {t for t in targets if not name.startswith(t + ".")} for name, targets in graph.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle():
    found = cycles(import_graph())
    assert not found, f"import cycles among project modules: {found}"


def package_of(name: str) -> str:
    """The package a module counts under in the package graph: its subpackage (hupbench.datagen.render.gl ->
    hupbench.datagen.render); a module at the top of hupbench is its own node (hupbench.cli)."""
    parts = name.split(".")
    depth = 3 if len(parts) > 3 and parts[1] in INSTALLED else 2
    return ".".join(parts[:depth])


def test_no_import_cycle_between_packages():
    """No two packages import each other, through any chain (datagen.render and datagen.dataset did)."""
    graph = defaultdict(set)
    for name, targets in import_graph().items():
        graph[package_of(name)] |= {package_of(t) for t in targets} - {package_of(name)}
    found = cycles(dict(graph))
    assert not found, f"import cycles among packages: {found}"


def test_no_upward_import():
    bad = [f"{name} imports {target}" for name, targets in import_graph().items() for target in targets
           if folder_of(target) in FORBIDDEN.get(folder_of(name), ())]
    assert not bad, bad


#: subpackage -> modules (prefixes) it must never import, as its __init__ docstring says
NEVER = {
    "hupbench.datagen.assets": ("hupbench.datagen.render", "hupbench.datagen.dataset", "hupbench.datagen.grasps"),
    "hupbench.datagen.render": ("hupbench.datagen.grasps", "hupbench.datagen.dataset"),
    "hupbench.datagen.dataset": ("hupbench.datagen.grasps",),
    "hupbench.datagen.grasps": ("hupbench.datagen.dataset",),
    "hupbench.training": ("hupbench.evaluation", "hupbench.inference", "hupbench.verbs", "hupbench.cli"),
    "hupbench.evaluation": ("hupbench.training", "hupbench.verbs", "hupbench.cli"),
    "hupbench.inference": ("hupbench.training", "hupbench.evaluation", "hupbench.verbs", "hupbench.cli"),
    "hupbench.verbs": ("hupbench.cli",),
    "hupbench.data": ("hupbench.evaluation", "hupbench.inference", "hupbench.verbs", "hupbench.cli"),
}
#: the torch-free inference path (predict runs where torch is not installed)
TORCH_FREE = ("hupbench.inference.predict", "hupbench.inference.images", "hupbench.inference.overlay",
              "hupbench.inference.model_file", "hupbench.inference.runtime", "hupbench.inference.tracking",
              "hupbench.inference.video",
              "hupbench.error_lines", "hupbench.cli")
#: datagen's shared modules at the top import no datagen subpackage
SHARED_TOP = ("hupbench.datagen.mesh_distance",)


def test_subpackages_import_only_what_their_docstring_allows():
    graph = import_graph()
    bad = []
    for name, targets in graph.items():
        for package, never in NEVER.items():
            if name == package or name.startswith(package + "."):
                bad += [f"{name} imports {t}" for t in targets if any(t == n or t.startswith(n + ".") for n in never)]
        if name in SHARED_TOP:
            bad += [f"{name} imports {t}" for t in targets if t.count(".") >= 3]
    assert not bad, bad


def test_nothing_imports_a_top_level_models_or_datagen():
    """Installed, there is no top-level ``models`` or ``datagen`` (a user's own folder of that name would shadow
    it): every file of the repository imports them as ``hupbench.models`` and ``hupbench.datagen``, and
    pyproject.toml installs nothing outside ``hupbench``."""
    import tomllib

    bad = []
    files = [REPO / "train.py"] + [p for folder in (*PACKAGES, "tests", "scripts", "benchmarks")
                                    for p in (REPO / folder).rglob("*.py")]
    for path in sorted(files):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([alias.name for alias in node.names] if isinstance(node, ast.Import) else
                     [node.module] if isinstance(node, ast.ImportFrom) and not node.level and node.module else [])
            bad += [f"{path.relative_to(REPO)}:{node.lineno} imports {n}" for n in names
                    if n.split(".")[0] in ("models", "datagen", "core")]
    assert not bad, bad
    setuptools = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    outside = [p for p in setuptools["packages"] if p.split(".")[0] != "hupbench"]
    assert not outside, f"pyproject.toml installs top-level packages {outside}"
    assert setuptools["package-dir"] == {"hupbench.conf": "conf", "hupbench.core": "core",
                                         "hupbench.datagen": "datagen", "hupbench.models": "models"}


def test_a_user_s_own_models_and_datagen_folders_do_not_shadow_ours(tmp_path):
    """Run from a folder holding a user's own ``models`` and ``datagen`` packages, hupbench builds its model and
    reads its keypoints from its own, and the user's stay importable under their names."""
    import subprocess
    import sys

    for name in ("models", "datagen"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text(f"MINE = {name!r}\n")
    code = ("import models, datagen; from hupbench.models.build import build_model; "
            "from hupbench.core import keypoints; "
            "m = build_model({'name': 'hopenet', 'backbone': 'resnet10'}); "
            "print(models.MINE, datagen.MINE, keypoints.NUM_KEYPOINTS, type(m).__module__)")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == ["models", "datagen", "29", "hupbench.models.hopenet"]


def test_every_subpackage_says_what_it_owns_and_may_import():
    for init in sorted(p for package in PACKAGES for p in (REPO / package).rglob("__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        assert "May import" in doc, f"{init.relative_to(REPO)}: its docstring must say what the package may import"


def test_no_file_or_function_too_long():
    too_long = []
    for name, path in sorted(project_modules().items()):
        lines = path.read_text().splitlines()
        if len(lines) > MAX_FILE_LINES:
            too_long.append(f"{path.relative_to(REPO)}: {len(lines)} lines")
        for node in ast.walk(ast.parse("\n".join(lines))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    too_long.append(f"{path.relative_to(REPO)}:{node.lineno} {node.name}(): {length} lines")
    assert not too_long, too_long


def test_training_reads_in_one_sitting():
    """``train()``, the loop a reader follows from setup to summary, fits on a screen or two."""
    from hupbench.training.loop import train

    import inspect

    assert len(inspect.getsource(train).splitlines()) <= 80
    assert "OmegaConf.create" not in (REPO / "hupbench" / "training" / "loop.py").read_text()


def test_the_functions_that_run_a_verb_take_few_parameters():
    """What each verb of ``hupbench`` calls to run (the functions its CLI section imports from the packages)
    takes at most MAX_VERB_PARAMETERS parameters: a run's values travel as one typed object."""
    import importlib
    import inspect

    cli = ast.parse((REPO / "hupbench" / "cli.py").read_text())
    checked, bad = 0, []
    for node in ast.walk(cli):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("hupbench"):
            module = importlib.import_module(node.module)
            for alias in node.names:
                target = getattr(module, alias.name)
                if inspect.isfunction(target):
                    checked += 1
                    n = len(inspect.signature(target).parameters)
                    if n > MAX_VERB_PARAMETERS:
                        bad.append(f"{node.module}.{alias.name}: {n} parameters")
    assert checked >= 10, checked
    assert not bad, bad


def test_no_two_source_files_share_a_name():
    by_name = defaultdict(list)
    for path in project_modules().values():
        if path.name != "__init__.py":
            by_name[path.name].append(str(path.relative_to(REPO)))
    clashes = {k: v for k, v in by_name.items() if len(v) > 1}
    assert not clashes, clashes


def test_the_inference_path_imports_no_torch():
    """Importing the torch-free modules (in a fresh interpreter) loads no torch, at any depth."""
    import subprocess
    import sys

    code = ("import sys, importlib; [importlib.import_module(m) for m in %r]; "
            "sys.exit(3 if 'torch' in sys.modules else 0)" % (TORCH_FREE,))
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"importing {TORCH_FREE} loaded torch (exit {proc.returncode}): {proc.stderr[-2000:]}"


def test_predict_imports_no_generator_module_and_no_torch():
    """``hupbench predict`` runs from the core and the inference package alone: importing it loads no module of
    the generator (``hupbench.datagen``) and no torch."""
    import subprocess
    import sys

    code = ("import sys, hupbench.inference.predict; "
            "print([m for m in sys.modules if m.startswith('hupbench.datagen') or m == 'torch'])")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "[]"



def test_tests_mirror_the_packages():
    """Each test folder is a package folder (tests/datagen/dataset for datagen/dataset), each test module's
    name is unique (pytest imports them by name), and test modules import helpers, never each other."""
    tests = REPO / "tests"
    folders = {p.parent.relative_to(tests) for p in tests.rglob("test_*.py")}
    strays = sorted(str(f) for f in folders if f.parts and not (REPO / f).is_dir())
    assert not strays, f"test folders without a package of the same path: {strays}"
    names = defaultdict(list)
    for path in tests.rglob("test_*.py"):
        names[path.name].append(str(path.relative_to(tests)))
    assert not {k: v for k, v in names.items() if len(v) > 1}, names
    cross = []
    for path in tests.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(("test_", "conftest")):
                cross.append(f"{path.relative_to(tests)}:{node.lineno} imports {node.module}")
    assert not cross, f"import shared code from tests/helpers/ instead: {sorted(set(cross))}"
