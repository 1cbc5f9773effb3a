"""The stages of the package import only downwards (docs/architecture.md, "Stages").

Every import of a ``towerpipe`` module counts, also one inside a function: a stage never
reaches up, so no two modules can import each other in a circle across stages.
"""

from __future__ import annotations

import ast

import pytest

from conftest import REPO

SRC = REPO / "src" / "towerpipe"

#: Rank of each stage, lowest first (the base of rank 1 imports nothing above it).
STAGES = {
    **dict.fromkeys(("errors", "classes", "progress", "config", "__init__"), 1),
    "io": 2,
    "preprocess": 3,
    "model": 4,
    "towers": 5,
    "inference": 6,
    "training": 7,
    "products": 8,
    "evaluation": 9,
    "jobs": 10,
    **dict.fromkeys(("cli", "bench"), 11),
}
#: The synthetic data generator stands beside the pipeline: it may use these only.
SYNTH_MAY_IMPORT = {"errors", "classes", "synth"}


def _stage(parts: tuple[str, ...]) -> str:
    return parts[0].removesuffix(".py")


def _imports(path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "towerpipe":
            mod = node.module.split(".")
            if len(mod) == 1:  # from towerpipe import x: a module, or a name of the package's __init__
                out.update(
                    a.name if (SRC / a.name).exists() or (SRC / f"{a.name}.py").exists() else "__init__"
                    for a in node.names
                )
            else:
                out.add(mod[1])
        elif isinstance(node, ast.Import):
            for a in node.names:
                mod = a.name.split(".")
                if mod[0] == "towerpipe" and len(mod) > 1:
                    out.add(mod[1])
    return out


MODULES = sorted(p for p in SRC.rglob("*.py"))


@pytest.mark.parametrize("path", MODULES, ids=[str(p.relative_to(SRC)) for p in MODULES])
def test_a_module_imports_only_its_stage_and_below(path):
    own = _stage(path.relative_to(SRC).parts)
    used = _imports(path) - {own}
    if own == "synth":
        assert used <= SYNTH_MAY_IMPORT, f"{path.relative_to(REPO)} imports {sorted(used - SYNTH_MAY_IMPORT)}"
        return
    assert own in STAGES, f"{path.relative_to(REPO)}: stage {own!r} is not in STAGES (add it, docs/architecture.md)"
    up = sorted(u for u in used if u != "synth" and STAGES.get(u, 99) >= STAGES[own] and STAGES[own] > 1)
    up += sorted(u for u in used if STAGES[own] == 1 and STAGES.get(u, 99) > 1)
    assert not up, f"{path.relative_to(REPO)} (stage {own}) imports {up}, which are not below it"


def test_no_module_over_500_lines():
    long = {str(p.relative_to(SRC)): n for p in MODULES if (n := len(p.read_text().splitlines())) > 500}
    assert not long
