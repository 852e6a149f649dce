"""Fraction of the package's public functions, methods and classes that have a docstring.

    python benchmarks/docstring_coverage.py [--list]

Public: a module-level function or class, or a method of a public class, whose name does not start
with an underscore (dunder methods excluded), in ``src/edofproj`` (the CLI's ``register``/``run``
entry points of ``commands/`` included). Two counts are printed side by side:

* **own docstring**: the definition itself has one (read from the source with :mod:`ast`);
* **own or inherited**: a method without its own docstring also counts when it overrides a method of
  an ``edofproj`` base class that has one, found along the class's method resolution order as
  :func:`inspect.getdoc` does (a property through its getter). Docstrings of bases outside the
  package (``torch.nn.Module.forward``'s generic text) do not count, and a class counts on its own
  docstring only (a dataclass's generated signature is not documentation).

``--list`` prints the definitions without their own docstring; those that inherit one are marked
with the base method whose docstring they show.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import inspect
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "edofproj"
PACKAGE = SRC.name


def public_definitions(path: Path):
    """Yield ``(qualified name, class name or None, node)`` for the public definitions of one file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and not node.name.startswith("_"):
            yield node.name, None, node
            if isinstance(node, ast.ClassDef):
                for item in node.body:
                    if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) and not item.name.startswith("_"):
                        yield f"{node.name}.{item.name}", node.name, item


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _function_of(attribute):
    """The function behind a class attribute (a property's getter, a static or class method's function)."""
    if isinstance(attribute, property):
        return attribute.fget
    if isinstance(attribute, (staticmethod, classmethod)):
        return attribute.__func__
    return attribute


def inherited_from(module: str, class_name: str, method_name: str) -> str | None:
    """The ``edofproj`` base-class method whose docstring ``class_name.method_name`` shows, or None."""
    cls = getattr(importlib.import_module(module), class_name, None)
    if not inspect.isclass(cls):
        return None
    for base in inspect.getmro(cls)[1:]:
        if not base.__module__.startswith(PACKAGE + ".") or method_name not in base.__dict__:
            continue
        if inspect.getdoc(_function_of(base.__dict__[method_name])):
            return f"{base.__module__}.{base.__qualname__}.{method_name}"
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--list", action="store_true", help="print the definitions without their own docstring")
    args = parser.parse_args()
    sys.path.insert(0, str(SRC.parent))
    total, own, inherited, missing = 0, 0, 0, []
    for path in sorted(SRC.rglob("*.py")):
        for name, class_name, node in public_definitions(path):
            total += 1
            if ast.get_docstring(node):
                own += 1
                inherited += 1
                continue
            base = inherited_from(module_name(path), class_name, node.name) if class_name else None
            inherited += base is not None
            mark = f"  (inherits {base})" if base else ""
            missing.append(f"{path.relative_to(SRC.parent)}:{node.lineno} {name}{mark}")
    print(
        f"public definitions: {total}; with their own docstring: {own} ({100 * own / total:.1f} %); "
        f"own or inherited: {inherited} ({100 * inherited / total:.1f} %)"
    )
    if args.list:
        print("\n".join(missing))


if __name__ == "__main__":
    main()
