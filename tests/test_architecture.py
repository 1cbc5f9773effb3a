"""docs/architecture.md: its module map is the one ``scripts/architecture.py`` makes from the tree."""

from __future__ import annotations

import subprocess
import sys

from conftest import REPO

ROOT = REPO
SCRIPT = ROOT / "scripts" / "architecture.py"


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, check=False)


def test_module_map_is_current():
    proc = _run("--check")
    assert proc.returncode == 0, proc.stderr + "\nrun: python scripts/architecture.py"


def test_stale_map_is_found_and_rewritten(tmp_path):
    src = tmp_path / "pkg"
    (src / "io").mkdir(parents=True)
    (src / "__init__.py").write_text('"""The package."""\n')
    (src / "errors.py").write_text('"""Exceptions.\n\nMore text.\n"""\n')
    (src / "io" / "__init__.py").write_text('"""Files."""\n')
    (src / "io" / "las.py").write_text('"""Reading :class:`Block` files,\nwrapped | piped."""\n')
    doc = tmp_path / "architecture.md"
    doc.write_text("# Title\n\n<!-- modules:begin -->\nold\n<!-- modules:end -->\n\nkept\n")
    assert _run("--check", "--doc", str(doc), "--src", str(src)).returncode == 1
    assert _run("--doc", str(doc), "--src", str(src)).returncode == 0
    assert _run("--check", "--doc", str(doc), "--src", str(src)).returncode == 0
    assert doc.read_text() == (
        "# Title\n\n<!-- modules:begin -->\n"
        "### `towerpipe`\n\nThe package.\n\n| module | what it owns |\n|---|---|\n"
        "| `errors.py` | Exceptions. |\n\n"
        "### `towerpipe.io`\n\nFiles.\n\n| module | what it owns |\n|---|---|\n"
        "| `io/las.py` | Reading `Block` files, wrapped \\| piped. |\n\n"
        "<!-- modules:end -->\n\nkept\n"
    )
    # a new module makes the map stale again
    (src / "io" / "tiles.py").write_text('"""Tiles."""\n')
    assert _run("--check", "--doc", str(doc), "--src", str(src)).returncode == 1
