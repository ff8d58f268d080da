"""The layers of docs/architecture.md, checked on the source: who may import whom, no cycles, and no import
inside a function without its stated reason.

The import names map onto top-level folders (``nfal.models`` is ``models/``, pyproject's package-dir), so
tools that walk ``nfal/`` alone miss the layers; this check reads every folder of :data:`LAYERS` itself.
"""

from __future__ import annotations

import ast
import functools
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Import name -> folder, as pyproject.toml's package-dir maps them.
FOLDERS = {"nfal.models": "models", "nfal.fmus": "fmus", "nfal.orchestration": "orchestration", "nfal.hil": "hil",
           "nfal": "nfal"}
#: Layer -> the layers it may import besides itself and the foundation. Each layer is a folder: the foundation is
#: the modules of nfal/ itself, "applications" nfal/apps/, "cli" nfal/cli/ (and nfal/__main__.py, its entry point).
ALLOWED = {
    "foundation": set(),
    "models": set(),
    "fmus": {"models", "hil"},
    "orchestration": set(),
    "hil": set(),
    "applications": {"models", "fmus", "orchestration", "hil"},
    "cli": {"models", "fmus", "orchestration", "hil", "applications"},
}
#: nfal's subfolders that are layers, and the layer each is.
SUBFOLDER_LAYERS = {"models": "models", "fmus": "fmus", "orchestration": "orchestration", "hil": "hil",
                    "apps": "applications", "cli": "cli"}


def layer_of(module: str) -> str | None:
    """The layer of a module of nfal (None for other packages), read off its folder."""
    parts = module.split(".")
    if parts[0] != "nfal":
        return None
    if module == "nfal.__main__":
        return "cli"
    if len(parts) > 2 or (len(parts) == 2 and parts[1] in SUBFOLDER_LAYERS):
        return SUBFOLDER_LAYERS.get(parts[1])
    return "foundation"


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the package: import name -> file."""
    found = {}
    for package, folder in FOLDERS.items():
        for path in sorted((root / folder).rglob("*.py")):
            relative = path.relative_to(root / folder).with_suffix("").parts
            if package == "nfal" and relative and relative[0] in FOLDERS.keys() - {"nfal"}:
                continue
            name = ".".join((package, *relative))
            found[name.removesuffix(".__init__")] = path
    return found


def parsed(path: Path) -> tuple[list[str], ast.Module]:
    """(lines, syntax tree) of a source file, parsed once per content for all the checks in this process."""
    text = path.read_text(encoding="utf-8")
    return text.splitlines(), _syntax_tree(text)


@functools.lru_cache(maxsize=None)
def _syntax_tree(text: str) -> ast.Module:
    return ast.parse(text)


def import_statements(path: Path) -> tuple[tuple[ast.Import | ast.ImportFrom, bool], ...]:
    """Every import statement of a source file, in line order, and whether it is inside a function."""
    return _import_statements(path.read_text(encoding="utf-8"))


@functools.lru_cache(maxsize=None)
def _import_statements(text: str) -> tuple[tuple[ast.Import | ast.ImportFrom, bool], ...]:
    found, stack = [], [(_syntax_tree(text), False)]
    while stack:  # one walk of the statements (an import is never inside an expression)
        node, local = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            found.append((node, local))
            continue
        local = local or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        stack.extend((child, local) for child in ast.iter_child_nodes(node) if not isinstance(child, ast.expr))
    return tuple(sorted(found, key=lambda item: (item[0].lineno, item[0].col_offset)))


def imports(module: str, path: Path) -> list[tuple[str, int, bool]]:
    """(imported nfal module, line, inside a function) for every import of nfal in ``path``."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node, local in import_statements(path):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            names = [base] + [f"{base}.{alias.name}" for alias in node.names]  # a submodule or a name in it
        for name in names:
            if name.split(".")[0] == "nfal":
                found.append((name, node.lineno, local))
    return found


def violations(root: Path = ROOT) -> list[str]:
    """Every import that crosses the layers the wrong way, as ``file:line: a (layer) imports b (layer)``."""
    known = modules(root)
    problems = []
    for module, path in known.items():
        mine = layer_of(module)
        for name, line, _ in imports(module, path):
            if name not in known:  # a name inside a module, not a module
                continue
            theirs = layer_of(name)
            if theirs not in (mine, "foundation") and theirs not in ALLOWED[mine]:
                problems.append(f"{path.relative_to(root)}:{line}: {module} ({mine}) imports {name} ({theirs})")
            if mine == "foundation" and theirs == "foundation" and name == module:
                problems.append(f"{path.relative_to(root)}:{line}: {module} imports itself")
    return problems


def layer_cycles(root: Path = ROOT) -> list[tuple[str, str]]:
    """Pairs of layers that import each other (at module level or inside functions)."""
    known = modules(root)
    edges = {(layer_of(module), layer_of(name)) for module, path in known.items()
             for name, _, _ in imports(module, path) if name in known}
    return sorted((a, b) for a, b in edges if a < b and (b, a) in edges)


def unexplained_local_imports(root: Path = ROOT) -> list[str]:
    """Imports inside a function (of any package) with no comment on their line or on the line above the
    block of imports they belong to: each needs its stated reason (an optional or slow dependency)."""
    found = []
    for module, path in modules(root).items():
        lines = parsed(path)[0]
        for node, local in import_statements(path):
            if not local:
                continue
            first = node.lineno - 1
            while first > 0 and lines[first - 1].strip().startswith(("import ", "from ")):
                first -= 1  # the block of imports this one is in
            block = lines[first:node.end_lineno]
            above = lines[first - 1] if first > 0 else ""
            if not ("#" in above or any("#" in line for line in block)):
                found.append(f"{path.relative_to(root)}:{node.lineno}: {lines[node.lineno - 1].strip()}")
    return found


def test_every_module_is_in_a_layer():
    found = modules()
    assert "nfal.models.plant" in found and "nfal.fmus.base" in found and "nfal.orchestration.master" in found
    assert all(layer_of(name) for name in found)


def test_the_layers_are_kept():
    assert violations() == []


def test_no_two_layers_import_each_other():
    assert layer_cycles() == []


def test_every_import_inside_a_function_says_why():
    assert unexplained_local_imports() == []


def test_the_check_catches_a_deliberate_violation(tmp_path):
    for package, folder in FOLDERS.items():
        (tmp_path / folder).mkdir(exist_ok=True)
        (tmp_path / folder / "__init__.py").write_text("")
    (tmp_path / "nfal" / "errors.py").write_text("")
    (tmp_path / "models" / "plant.py").write_text("from nfal.errors import NfalError\n")
    (tmp_path / "fmus" / "base.py").write_text("from nfal.models import plant\n")
    assert violations(tmp_path) == [] and layer_cycles(tmp_path) == []
    (tmp_path / "models" / "plant.py").write_text(textwrap.dedent("""\
        from nfal.errors import NfalError


        def plant():
            from nfal.fmus.base import NfalSlave
    """))
    assert violations(tmp_path) == ["models/plant.py:5: nfal.models.plant (models) imports nfal.fmus.base (fmus)"]
    assert layer_cycles(tmp_path) == [("fmus", "models")]
    assert unexplained_local_imports(tmp_path) == ["models/plant.py:5: from nfal.fmus.base import NfalSlave"]
    (tmp_path / "orchestration" / "run.py").write_text("from ..apps import fig7\nfrom nfal.fmus import base\n")
    (tmp_path / "nfal" / "apps").mkdir()
    (tmp_path / "nfal" / "apps" / "__init__.py").write_text("")
    (tmp_path / "nfal" / "apps" / "fig7.py").write_text("")
    assert violations(tmp_path)[1:] == [
        "orchestration/run.py:1: nfal.orchestration.run (orchestration) imports nfal.apps (applications)",
        "orchestration/run.py:1: nfal.orchestration.run (orchestration) imports nfal.apps.fig7 (applications)",
        "orchestration/run.py:2: nfal.orchestration.run (orchestration) imports nfal.fmus (fmus)",
        "orchestration/run.py:2: nfal.orchestration.run (orchestration) imports nfal.fmus.base (fmus)"]



#: The longest a function may be, in lines of code (its docstring not counted); numba kernels are exempt.
MAX_FUNCTION_LINES = 80


def long_functions(root: Path = ROOT) -> list[str]:
    """Functions longer than :data:`MAX_FUNCTION_LINES` (without the docstring), numba kernels left out."""
    found = []
    for module, path in modules(root).items():
        for node in ast.walk(parsed(path)[1]):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            if any("numba" in ast.unparse(decorator) for decorator in node.decorator_list):
                continue
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant):
                length = node.end_lineno - node.lineno + 1 - (body[0].end_lineno - body[0].lineno + 1)
            else:
                length = node.end_lineno - node.lineno + 1
            if length > MAX_FUNCTION_LINES:
                found.append(f"{path.relative_to(root)}:{node.lineno}: {node.name} ({length} lines)")
    return found


def test_no_function_is_longer_than_80_lines():
    assert long_functions() == []


def test_no_test_module_imports_from_another():
    """What several test modules share lives in tests/helpers/ or conftest.py: importing a test module from another
    runs its module-level code and collects its tests twice over in a reader's head."""
    offenders = []
    for path in sorted((ROOT / "tests").glob("test_*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([node.module or ""] if isinstance(node, ast.ImportFrom)
                     else [alias.name for alias in node.names] if isinstance(node, ast.Import) else [])
            offenders += [f"{path.name} imports {name}" for name in names if name.split(".")[0].startswith("test_")]
    assert offenders == []
