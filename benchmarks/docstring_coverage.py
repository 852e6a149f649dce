"""Fraction of the package's public functions, methods and classes that have a docstring.

    python benchmarks/docstring_coverage.py [--list]

Public: a module-level function or class, or a method of a public class, whose name does not start
with an underscore (dunder methods excluded), in ``src/edofproj`` (the CLI's ``register``/``run``
entry points of ``commands/`` included). ``--list`` prints the undocumented ones.
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "edofproj"


def public_definitions(path: Path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and not node.name.startswith("_"):
            yield node.name, node
            if isinstance(node, ast.ClassDef):
                for item in node.body:
                    if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) and not item.name.startswith("_"):
                        yield f"{node.name}.{item.name}", item


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--list", action="store_true", help="print the undocumented definitions")
    args = parser.parse_args()
    total, documented, missing = 0, 0, []
    for path in sorted(SRC.rglob("*.py")):
        for name, node in public_definitions(path):
            total += 1
            if ast.get_docstring(node):
                documented += 1
            else:
                missing.append(f"{path.relative_to(SRC.parent)}:{node.lineno} {name}")
    print(f"public definitions with a docstring: {documented} of {total} ({100 * documented / total:.1f} %)")
    if args.list:
        print("\n".join(missing))


if __name__ == "__main__":
    main()
