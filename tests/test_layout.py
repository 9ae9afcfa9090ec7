"""The package layout shows the pipeline's layers and imports go one way: a module
imports only from its own layer or from layers below it (README, "Architecture")."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "src" / "bayescalib"

#: lowest first; a layer may import from itself and from the layers before it
LAYERS = [
    {"config", "_process"},
    {"geometry"},
    {"io"},
    {"measures"},
    {"inference", "models"},
    {"plotting", "study", "config_reference"},
    {"stages"},
    {"diagnosis"},
    {"execution"},
    {"cli", "__main__", "__init__"},
]
RANK = {name: k for k, layer in enumerate(LAYERS) for name in layer}


def _room(module: str) -> str:
    """The layer name of ``bayescalib.x.y`` (its first component below the package)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 \
                and node.module.startswith("bayescalib"):
            if node.module != "bayescalib":
                out.add(node.module)
            else:  # from bayescalib import x: a module of the package, or its __init__
                out |= {f"bayescalib.{a.name}" if a.name in RANK else "bayescalib"
                        for a in node.names}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("bayescalib.")}
    return out


def test_every_module_lives_in_a_named_layer():
    rooms = {p.relative_to(PKG).parts[0].removesuffix(".py") for p in PKG.rglob("*.py")}
    assert rooms <= set(RANK), f"modules outside the layers: {sorted(rooms - set(RANK))}"


def test_imports_go_one_way_down_the_layers():
    upward = []
    for path in PKG.rglob("*.py"):
        me = path.relative_to(PKG).parts[0].removesuffix(".py")
        for module in _imports(path):
            other = _room(module)
            if other != me and RANK[other] > RANK[me]:
                upward.append(f"{path.relative_to(PKG)} imports {module}")
    assert not upward, "imports against the layering:\n" + "\n".join(sorted(upward))


def test_no_module_shares_its_name_with_a_function_of_its_package():
    """Importing ``pkg.x`` rebinds the package's attribute ``x`` to the module: a
    function ``x`` defined in ``pkg/__init__.py`` would be replaced by it."""
    clashes = []
    for init in PKG.rglob("__init__.py"):
        tree = ast.parse(init.read_text())
        names = {n.name for n in tree.body
                 if isinstance(n, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef))}
        modules = {p.stem for p in init.parent.glob("*.py")} | \
            {p.name for p in init.parent.iterdir() if (p / "__init__.py").is_file()}
        clashes += [f"{init.parent.relative_to(PKG)}: {n}" for n in sorted(names & modules)]
    assert not clashes, clashes
