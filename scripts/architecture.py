"""Regenerate the module map of ``docs/architecture.md`` from the source tree.

One row per module of ``src/towerpipe`` (its path and the first paragraph of its
docstring), grouped by package, each group headed by the package's ``__init__``
docstring; top-level modules first, then the subpackages in stage order (lowest
first). The map is written between the ``<!-- modules:begin -->`` and
``<!-- modules:end -->`` comments of the document; the rest is left as it is.

Usage::

    python scripts/architecture.py            # rewrite the map
    python scripts/architecture.py --check    # exit 1 if the map is stale
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "towerpipe"
DOC = ROOT / "docs" / "architecture.md"
BEGIN, END = "<!-- modules:begin -->", "<!-- modules:end -->"
#: Subpackages in stage order, lowest first (a lower stage never imports a higher one);
#: ``synth`` is the data generator beside them. Others found in the tree follow, sorted.
STAGES = (
    "io",
    "preprocess",
    "model",
    "training",
    "inference",
    "towers",
    "products",
    "products/qa",
    "evaluation",
    "jobs",
    "synth",
)


def summary(path: Path) -> str:
    """The first paragraph of a module's docstring, on one line."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    para = doc.strip().split("\n\n", 1)[0]
    return " ".join(para.split()) or "(no docstring)"


def _cell(text: str) -> str:
    """A docstring's reStructuredText as Markdown in a table cell."""
    text = re.sub(r":[\w:]+:`~?([^`]+)`", r"`\1`", text)  # :func:`~a.b` -> `a.b`
    return text.replace("``", "`").replace("|", "\\|")


def packages(src: Path = SRC) -> list[Path]:
    """Package directories below ``src`` (relative to it), top level first, then stage order."""
    found = sorted(p.parent.relative_to(src) for p in src.rglob("__init__.py"))
    rank = {Path(s): i for i, s in enumerate(STAGES)}
    return sorted(found, key=lambda p: (p != Path("."), rank.get(p, len(STAGES)), p.as_posix()))


def module_map(src: Path = SRC) -> str:
    """The Markdown of the module map (without the marker comments)."""
    out: list[str] = []
    for pkg in packages(src):
        d = src / pkg
        name = "towerpipe" if pkg == Path(".") else "towerpipe." + ".".join(pkg.parts)
        out += [f"### `{name}`", "", _cell(summary(d / "__init__.py")), "", "| module | what it owns |", "|---|---|"]
        for f in sorted(d.glob("*.py")):
            if f.name != "__init__.py":
                out.append(f"| `{f.relative_to(src).as_posix()}` | {_cell(summary(f))} |")
        out.append("")
    return "\n".join(out)


def render(text: str, src: Path = SRC) -> str:
    """``text`` (the document) with its module map regenerated."""
    try:
        head, rest = text.split(BEGIN, 1)
        _, tail = rest.split(END, 1)
    except ValueError:
        raise SystemExit(f"architecture.py: the document lacks the {BEGIN} / {END} markers") from None
    return f"{head}{BEGIN}\n{module_map(src)}\n{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true", help="exit 1 if the document's module map is stale")
    p.add_argument("--doc", type=Path, default=DOC, help="the document (default: docs/architecture.md)")
    p.add_argument("--src", type=Path, default=SRC, help="the package directory (default: src/towerpipe)")
    args = p.parse_args(argv)
    text = args.doc.read_text(encoding="utf-8")
    new = render(text, args.src)
    if args.check:
        if new != text:
            print(f"{args.doc}: the module map is stale; run python scripts/architecture.py", file=sys.stderr)
            return 1
        return 0
    if new != text:
        args.doc.write_text(new, encoding="utf-8")
        print(f"{args.doc}: module map updated")
    return 0


if __name__ == "__main__":
    sys.exit(main())
