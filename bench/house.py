"""The house's measures, as the fourth pass counts them: JSON lines.

For ``reach/``, ``oracles/`` and ``ros_bridge/`` (or the folders given): files and lines; modules over 500 lines;
functions over 60 lines (``ast``, decorators aside); functions with cyclomatic complexity over 15 (radon); classes
with more than 20 own methods; the deepest chain of classes with behaviour (a class counts when it defines a method
and is neither a protocol, an abstract base nor an exception); comments and docstrings naming a session or an issue.
Usage::

    python bench/house.py [FOLDER ...]
"""

from __future__ import annotations

import ast
import json
import re
import sys
from pathlib import Path

from radon.complexity import cc_visit

ROOTS = ("reach", "oracles", "ros_bridge")
NOTEBOOK = re.compile(r"\b(session|issue)s? ?\d+", re.IGNORECASE)


def _chains(trees: list[ast.Module]) -> list[tuple[int, str]]:
    """Each class with behaviour and the length of its chain of classes with behaviour."""
    classes: dict[str, tuple[list[str], bool]] = {}
    for tree in trees:
        for node in ast.walk(tree):
            if not isinstance(node, ast.ClassDef):
                continue
            bases = [b.id if isinstance(b, ast.Name) else b.attr if isinstance(b, ast.Attribute) else "" for b in
                     node.bases]
            methods = [m for m in node.body if isinstance(m, (ast.FunctionDef, ast.AsyncFunctionDef))]
            abstract = any(getattr(d, "id", getattr(d, "attr", "")) == "abstractmethod" for m in methods
                           for d in m.decorator_list)
            plain = {"Protocol", "ABC", "Exception", "NamedTuple"}
            behaves = bool(methods) and not abstract and not plain & set(bases) and not node.name.endswith("Error")
            classes[node.name] = (bases, behaves)

    def length(name: str, seen: frozenset[str] = frozenset()) -> int:
        if name not in classes or name in seen:
            return 0
        bases, behaves = classes[name]
        return int(behaves) + max((length(b, seen | {name}) for b in bases), default=0)

    return sorted(((length(n), n) for n, (_, behaves) in classes.items() if behaves), reverse=True)


def main(roots: list[str]) -> None:
    files = [p for r in roots for p in sorted(Path(r).rglob("*.py"))]
    lines, big, long, complex_, fat, notes, trees = 0, [], [], {}, [], [], []
    for path in files:
        src = path.read_text(encoding="utf-8")
        n = src.count("\n")
        lines += n
        if n > 500:
            big.append((str(path), n))
        tree = ast.parse(src)
        trees.append(tree)
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno is not None:
                length = node.end_lineno - node.lineno + 1
                if length > 60:
                    long.append((f"{path}:{node.name}", length))
            if isinstance(node, ast.ClassDef):
                own = [m for m in node.body if isinstance(m, (ast.FunctionDef, ast.AsyncFunctionDef))]
                if len(own) > 20:
                    fat.append((f"{path}:{node.name}", len(own)))
        for block in cc_visit(src):
            for f in [block, *getattr(block, "methods", [])]:
                if not hasattr(f, "methods") and f.complexity > 15:
                    complex_[f"{path}:{f.fullname}"] = f.complexity
        notes += [f"{path}:{k}" for k, line in enumerate(src.splitlines(), 1)
                  if ("#" in line or '"""' in line) and NOTEBOOK.search(line)]
    chains = _chains(trees)
    rows = {"files": len(files), "lines": lines, "modules_over_500_lines": sorted(big, key=lambda t: -t[1]),
            "functions_over_60_lines": sorted(long, key=lambda t: -t[1]),
            "functions_complexity_over_15": sorted(complex_.items(), key=lambda t: -t[1]),
            "classes_over_20_methods": sorted(fat, key=lambda t: -t[1]),
            "deepest_class_chain": chains[:3], "comments_naming_a_session_or_issue": notes}
    print(json.dumps({"bench": "house", **{k: (len(v) if isinstance(v, list) and k not in ("deepest_class_chain",)
                                               else v) for k, v in rows.items()},
                      "deepest": chains[0][0] if chains else 0}))
    for key, value in rows.items():
        if isinstance(value, list) and value:
            print(json.dumps({"bench": "house", "what": key, "items": value}))


if __name__ == "__main__":
    main(sys.argv[1:] or list(ROOTS))
