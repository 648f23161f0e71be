"""The training package's layering: each module imports only modules below it, lazily or not.

(Line caps per module were dropped: they measured lines, not concerns, and code was
packed with formatter escapes to meet them; the last test keeps them out.)"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "minitaur_env" / "training"

# Lowest first. A module may import modules of lower layers only: a new module must be
# placed here, and an import that climbs fails the test.
LAYERS = [
    {"noise"},
    {
        "files",
        "policies",
        "sbx_policies",
        "progress",
        "runtime",
        "single_env",
        "vec_env",
        "export",
        "seeds",
    },
    {
        "run_folder",
        "plotting",
        "algorithms",
        "envs",
        "search_space",
        "replay_buffer",
    },
    {"aggregate", "safe_load", "hyperparams"},
    {"config", "evaluation", "results"},
    {"checkpoints", "onnx_export", "video"},
    {"callbacks", "hub", "shipping"},
    {"experiment"},
    {"trial", "cli"},
    {"sweeps", "sweep_summary"},
    {"commands"},
]
LAYER_OF = {name: index for index, layer in enumerate(LAYERS) for name in layer}


def imported_modules(path: Path) -> set[str]:
    """The package's modules that ``path`` imports anywhere (in functions too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            parts = node.module.split(".")
            if parts[:2] == ["minitaur_env", "training"]:
                if len(parts) > 2:
                    found.add(parts[2])
                else:  # from minitaur_env.training import <module or name>
                    found |= {a.name for a in node.names if (PACKAGE / f"{a.name}.py").is_file()}
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[:2] == ["minitaur_env", "training"] and len(parts) > 2:
                    found.add(parts[2])
    return found


MODULES = sorted(path.stem for path in PACKAGE.glob("*.py") if path.stem != "__init__")


def test_every_module_has_a_layer():
    assert set(MODULES) == set(LAYER_OF), "place new modules in LAYERS"


@pytest.mark.parametrize("module", MODULES)
def test_module_imports_only_lower_layers(module):
    climbing = {
        other
        for other in imported_modules(PACKAGE / f"{module}.py")
        if LAYER_OF.get(other, -1) >= LAYER_OF[module]
    }
    assert not climbing, f"{module} imports {sorted(climbing)}, which are not below it"


def test_the_layer_check_catches_an_upward_import(tmp_path):
    # negative control: a lazy import of a higher module, inside a function
    source = "def f():\n    from minitaur_env.training.experiment import Experiment\n"
    (tmp_path / "probe.py").write_text(source)
    assert imported_modules(tmp_path / "probe.py") == {"experiment"}


def documented_order() -> list[set[str]]:
    """docs/development.md's listing of minitaur_env/training/, one set of modules per line."""
    text = (PACKAGE.parents[1] / "docs" / "development.md").read_text()
    block = text.split("minitaur_env/training/ ", 1)[1].split("\nminitaur_env/cli.py", 1)[0]
    lines = []
    for line in block.splitlines()[1:]:
        names = line.strip().split("  ")[0]
        lines.append({name.strip().removesuffix(".py") for name in names.split(",")})
    return lines


def test_the_documented_layout_lists_every_module_below_what_it_imports():
    order = documented_order()
    listed = [name for line in order for name in line]
    assert sorted(listed) == MODULES, "docs/development.md must list each module once"
    above: set[str] = set()
    for line in order:
        for module in line:
            climbing = imported_modules(PACKAGE / f"{module}.py") - above - line
            assert not climbing, f"{module} imports {sorted(climbing)}, listed below it"
        above |= line


def test_no_code_is_held_out_of_the_formatter():
    # Formatter escapes were how lines were packed to meet the old caps; ruff owns layout.
    root = Path(__file__).resolve().parents[1]
    marker = "fmt: " + "skip"  # split, or this line would match
    held = [
        f"{path.relative_to(root)}:{number}"
        for folder in ("minitaur_env", "benchmarks", "tests")
        for path in sorted((root / folder).rglob("*.py"))
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if marker in line
    ]
    assert held == []
