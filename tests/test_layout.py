"""The package's layout: its modules import one another without cycles.

The import graph is read from the sources with `ast`, every import counted (those inside
functions too, which hide a cycle from Python at import time but not from a reader).
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import icefarm

PACKAGE_DIR = Path(icefarm.__file__).resolve().parent


def source_tree(path: Path) -> ast.Module:
    """The parsed source of ``path``; each text is parsed once per session (the layout tests
    read every module several times)."""
    return _parsed(path.read_text(), str(path))


@functools.cache
def _parsed(text: str, name: str) -> ast.Module:
    return ast.parse(text, name)


def module_files(package_dir: Path) -> dict[str, Path]:
    """Dotted module name to source file, for every ``.py`` under ``package_dir``."""
    root = package_dir.name
    modules = {}
    for path in sorted(package_dir.rglob("*.py")):
        parts = path.relative_to(package_dir).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join((root, *parts))] = path
    return modules


def import_graph(package_dir: Path) -> dict[str, set[str]]:
    """Module to the modules of the same package it imports, anywhere in its source.

    ``from .x import y`` counts as importing ``x``, and ``x.y`` too where that is a module;
    ``from . import y`` as importing ``y``.
    """
    modules = module_files(package_dir)
    root = package_dir.name
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        here = name.split(".") if is_package else name.split(".")[:-1]
        for node in ast.walk(source_tree(path)):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = here[:len(here) - node.level + 1]
                    stem = ".".join(base + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                named = [f"{stem}.{alias.name}" for alias in node.names]
                targets = [t for t in named if t in modules]
                if node.module or not targets:
                    targets.append(stem)
            for target in targets:
                # ``import a.b.c`` imports a.b.c itself; count the deepest module of ours it names
                while target and target not in modules and target.startswith(root + "."):
                    target = target.rpartition(".")[0]
                if target in modules and target != name:
                    graph[name].add(target)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The modules that import one another in a ring: strongly connected components of two or more."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[set[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(component)
    return found




def test_no_module_of_icefarm_imports_itself_back():
    graph = import_graph(PACKAGE_DIR)
    assert len(graph) > 50 and graph["icefarm.sheets.draw"]  # the graph is read, not empty
    rings = [" <-> ".join(sorted(ring)) for ring in cycles(graph)]
    assert not rings, "modules that import one another: " + "; ".join(rings)


def test_packages_import_downward_only():
    """Each subpackage (``stages``, ``scene``, ``farm``, ...) and each top-level module taken as
    one unit: no two units import each other, directly or around a ring."""
    units: dict[str, set[str]] = {}
    for module, imported in import_graph(PACKAGE_DIR).items():
        unit = ".".join(module.split(".")[:2])
        units.setdefault(unit, set()).update(".".join(m.split(".")[:2]) for m in imported)
    for unit, imported in units.items():
        imported.discard(unit)
    assert {"icefarm.stages", "icefarm.scene", "icefarm.farm", "icefarm.sheets", "icefarm.cli",
            "icefarm.job"} <= set(units)
    rings = [" <-> ".join(sorted(ring)) for ring in cycles(units)]
    assert not rings, "packages that import one another: " + "; ".join(rings)


def test_a_cycle_through_an_import_inside_a_function_is_found(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from .low import x\n")
    (pkg / "sub" / "low.py").write_text("x = 1\n")
    (pkg / "top.py").write_text("from .sub.low import x\n\ndef later():\n    from . import middle\n")
    (pkg / "middle.py").write_text("import pkg.top\n")
    graph = import_graph(pkg)
    assert graph["pkg.top"] == {"pkg.sub.low", "pkg.middle"}
    assert graph["pkg.middle"] == {"pkg.top"} and graph["pkg.sub"] == {"pkg.sub.low"}
    assert cycles(graph) == [{"pkg.middle", "pkg.top"}]
    (pkg / "middle.py").write_text("from .sub import low\n")
    graph = import_graph(pkg)
    assert graph["pkg.middle"] == {"pkg.sub", "pkg.sub.low"} and cycles(graph) == []


# ------------------------------------------------------------------ the job-folder contract
# The names the job-folder contract must keep to itself, whatever icefarm.jobdir lists.
CONTRACT_NAMES = ("params.yaml", "timings.json", "done.json", "error.json", "ice.ply", "object.ply", "scene.xml",
                  "scene.pov", "scene.json", "views.json", "render.exr", "render.png", "landing.json", "drips.json",
                  "trajectories.json", "water.ply", "proxy.ply", "scene.usda", "growth.usda", "frames.json",
                  "jobs.csv", "manifest.resolved.yaml")
NAME_LITERALS_ALLOWED = 3


def name_literals(package_dir: Path, names, skip: str = "jobdir.py") -> list[str]:
    """``path:line: text`` for each occurrence of one of ``names`` in a string constant of the
    package's code (f-strings' text included; docstrings, which explain, and the module
    ``skip`` at the package's top left out). So does ``render_view`` as a file stem's start."""
    import re

    pattern = re.compile(r"(?<![a-z0-9_.])(" + "|".join(map(re.escape, sorted(names, key=len, reverse=True)))
                         + r")(?!\w)|render_view(?![a-z_])")
    found = []
    for path in sorted(package_dir.rglob("*.py")):
        if path.parent == package_dir and path.name == skip:
            continue
        tree = source_tree(path)
        docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                      if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                      and node.body and isinstance(node.body[0], ast.Expr)
                      and isinstance(node.body[0].value, ast.Constant)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
                found += [f"{path.relative_to(package_dir.parent)}:{node.lineno}: {m.group(0)}"
                          for m in pattern.finditer(node.value)]
    return found


def test_artifact_names_are_written_once_in_the_job_folder_contract():
    """Every job- and sweep-folder file name is a constant of icefarm.jobdir; other modules
    use the constants (at most three literals elsewhere)."""
    from icefarm import jobdir

    assert set(CONTRACT_NAMES) <= set(jobdir.FILE_NAMES)
    found = name_literals(PACKAGE_DIR, set(jobdir.FILE_NAMES) | set(CONTRACT_NAMES))
    assert len(found) <= NAME_LITERALS_ALLOWED, "artifact names outside icefarm/jobdir.py:\n" + "\n".join(found)


def test_the_name_literal_scan_finds_code_and_skips_docstrings(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "jobdir.py").write_text('ICE = "ice.ply"\n')
    (pkg / "a.py").write_text('"""Reads ice.ply."""\n\ndef f(d, i):\n    """ice.ply again."""\n'
                              '    return (d / "ice.ply", f"{d}/render_view{i}.png", "slice.ply", "x_ice.ply",\n'
                              '            "render_view_seconds")\n')
    (pkg / "b.py").write_text('MESSAGE = f"no {1} in done.json"\n')
    assert name_literals(pkg, {"ice.ply", "done.json"}) == [
        "pkg/a.py:5: ice.ply", "pkg/a.py:5: render_view", "pkg/b.py:1: done.json"]


# ------------------------------------------------------------------ the packages' faces
FACES = ("bench", "export", "stages", "stages.surface", "scene", "farm", "sheets", "metaballs")


def imported_from(package_dir: Path, package: str) -> set[str]:
    """The public names modules outside ``package`` (dotted, under the package's root) import
    from it or from its modules with ``from ... import``."""
    root = package_dir.name
    full = f"{root}.{package}"
    names = set()
    modules = module_files(package_dir)
    for name, path in modules.items():
        if name == full or name.startswith(full + "."):
            continue
        here = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        for node in ast.walk(source_tree(path)):
            if isinstance(node, ast.ImportFrom):
                base = here[:len(here) - node.level + 1] if node.level else []
                module = ".".join(base + ([node.module] if node.module else []))
                if module == full or module.startswith(full + "."):
                    submodules = {f"{module}.{alias.name}" for alias in node.names} & modules.keys()
                    names |= {alias.name for alias in node.names if not alias.name.startswith("_")
                              and f"{module}.{alias.name}" not in submodules}
    return names


def test_each_package_face_lists_the_names_the_rest_of_icefarm_imports_from_it():
    import importlib

    for package in FACES:
        module = importlib.import_module(f"icefarm.{package}")
        assert all(getattr(module, name) is not None for name in module.__all__), package
        missing = imported_from(PACKAGE_DIR, package) - set(module.__all__)
        assert not missing, f"icefarm.{package}.__all__ lacks {sorted(missing)}"


# ------------------------------------------------------------------ the shape of the code
MAX_PARAMS = 7
MAX_BODY_LINES = 80
MAX_MODULE_LINES = 500
# What still exceeds the limits, each with why: the list may only shrink.
SHAPE_EXCEPTIONS = {
    # numba-compiled kernel: its arguments are the arrays it reads, no record crosses njit
    "icefarm/stages/surface/coat_kernel.py:band_phi": "compiled kernel",
    # a renderer's sample, split by phase comments as Mitsuba's integrators are
    "icefarm/scene/icepath.py:sample": "renderer's sample",
    # the Python API's keyword arguments are `icefarm run`'s options, as a click command's are
    "icefarm/api.py:grow": "the API's options",
    "icefarm/job/spec.py:job_spec": "the API's options",
}


def _shapes(package_dir: Path):
    """``(module lines, {path:function: (parameters, body lines)})`` of the package's code;
    parameters count a public function's own (not ``self``), click commands left out."""
    modules, functions = {}, {}
    for path in sorted(package_dir.rglob("*.py")):
        name = str(path.relative_to(package_dir.parent))
        modules[name] = len(path.read_text().splitlines())
        for node in ast.walk(source_tree(path)):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            a = node.args
            count = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)
            count -= bool(a.args and a.args[0].arg in ("self", "cls"))
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                body = body[1:]  # the docstring
            lines = node.end_lineno - body[0].lineno + 1 if body else 0
            click = any("command" in ast.unparse(d) or "option" in ast.unparse(d) for d in node.decorator_list)
            public = not node.name.startswith("_") and not click
            functions[f"{name}:{node.name}"] = (count if public else 0, lines)
    return modules, functions


def test_functions_take_few_parameters_and_stay_short_and_modules_hold_one_topic():
    modules, functions = _shapes(PACKAGE_DIR)
    assert len(functions) > 500  # the package was read
    many = [f"{k} takes {n}" for k, (n, _) in functions.items() if n > MAX_PARAMS and k not in SHAPE_EXCEPTIONS]
    long = [f"{k} runs {n} lines" for k, (_, n) in functions.items()
            if n > MAX_BODY_LINES and k not in SHAPE_EXCEPTIONS]
    big = [f"{k} has {n} lines" for k, n in modules.items() if n > MAX_MODULE_LINES and k not in SHAPE_EXCEPTIONS]
    assert not (many or long or big), "\n".join(many + long + big)
    stale = [k for k in SHAPE_EXCEPTIONS if k.split(":")[0] not in modules
             or (":" in k and k not in functions)]
    assert not stale, f"exceptions for code that is gone: {stale}"
