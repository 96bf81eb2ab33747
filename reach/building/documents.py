"""A config's YAML document, read strictly, with the config it extends (``base``) merged under it.

PyYAML's safe loader, refusing what it would take silently or at great cost: a key given twice (it keeps the last), a
whole number of more digits than any key takes, and aliases that expand past what any config holds ("billion laughs").
Every error is a ConfigError naming the file and, where it can, the line.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from reach.errors import ConfigError


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """Mappings merge key by key; anything else in over replaces base."""
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


class _DuplicateKey(Exception):
    def __init__(self, key: str, line: int) -> None:
        super().__init__(key)
        self.key, self.line = key, line


class _StrictLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a mapping that gives a key twice (PyYAML keeps the last silently)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
            if key in seen:
                raise _DuplicateKey(str(key), key_node.start_mark.line + 1)
            seen.add(key)
        return super().construct_mapping(node, deep)  # type: ignore[no-any-return]

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        digits = sum(c.isdigit() for c in str(node.value))
        if digits > MAX_DIGITS:
            raise _TooLong(node.start_mark.line + 1, digits)
        return super().construct_yaml_int(node)  # type: ignore[no-untyped-call,no-any-return]


# The most digits of a whole number in a config: no key takes more than a seed's (a 400-digit stature overflowed the
# float it becomes; one of 4,301 digits is past Python's own limit for reading an int)
MAX_DIGITS = 20


class _TooLong(Exception):
    def __init__(self, line: int, digits: int) -> None:
        super().__init__(line, digits)
        self.line, self.digits = line, digits


_StrictLoader.add_constructor("tag:yaml.org,2002:int", _StrictLoader.construct_yaml_int)


# The most nodes a config may hold with its aliases expanded: the largest shipped config has about 1,500; a "billion
# laughs" of nested aliases (796 bytes) expands past 10^8 and took 2.7 GB before failing.
MAX_NODES = 200_000


class _TooLarge(Exception):
    pass


def _expanded(node: yaml.Node) -> None:
    """Count the nodes a composed document holds with every alias expanded, raising _TooLarge past MAX_NODES (each
    node's count computed once: linear in the document, not in its expansion)."""
    sizes: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(node, False)]
    while stack:
        n, done = stack.pop()
        if id(n) in sizes:
            continue
        children = ([c for pair in n.value for c in pair] if isinstance(n, yaml.MappingNode)
                    else list(n.value) if isinstance(n, yaml.SequenceNode) else [])
        if done:
            sizes[id(n)] = 1 + sum(sizes[id(c)] for c in children)
            if sizes[id(n)] > MAX_NODES:
                raise _TooLarge
        else:
            stack.append((n, True))
            stack.extend((c, False) for c in children if id(c) not in sizes)


def _one_line(exc: yaml.YAMLError) -> str:
    """A YAML error as one line: what is wrong, and where (PyYAML's own message spans several lines)."""
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    mark = getattr(exc, "problem_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    hint = " (YAML indents with spaces, not tabs)" if "'\\t'" in str(problem) else ""
    return f"{problem}{where}{hint}"


def _document(path: Path) -> Any:
    """The YAML document of one file, read strictly (see the module docstring)."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(path, "", f"cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(path, "", f"not UTF-8 text (byte {exc.start}): a config is a YAML file in UTF-8") from None
    loader = _StrictLoader(text)  # a SafeLoader subclass: safe
    try:
        node = loader.get_single_node()
        # Aliases are counted expanded before anything is built from them (a few nested ones multiply).
        if node is not None:
            _expanded(node)
        return loader.construct_document(node) if node is not None else None
    except _DuplicateKey as exc:
        raise ConfigError(path, exc.key, f"duplicate key (line {exc.line}); give each key once") from None
    except _TooLong as exc:
        raise ConfigError(path, "", f"line {exc.line}: a whole number of {exc.digits} digits; no key takes more than "
                                    f"{MAX_DIGITS}") from None
    except _TooLarge:
        raise ConfigError(path, "", f"holds over {MAX_NODES:,} values with its aliases (&name, *name) expanded; a "
                                    "config that large is a mistake or an attack") from None
    except RecursionError:
        raise ConfigError(path, "", "nested too deeply") from None
    except yaml.YAMLError as exc:
        raise ConfigError(path, "", f"not valid YAML: {_one_line(exc)}") from None
    finally:
        loader.dispose()


def read_yaml(path: Path, seen: tuple[Path, ...] = ()) -> Any:
    """A config document, with its ``base`` (a config it extends) merged under it.

    Relative paths (``base``, ``body.urdf``) are relative to the file naming them.
    """
    data = _document(path)
    if not isinstance(data, Mapping):
        return data
    data = dict(data)
    body = data.get("body")
    for key in ("urdf", "srdf"):  # files beside the config
        if isinstance(body, Mapping) and isinstance(body.get(key), str) and not Path(body[key]).is_absolute():
            body = data["body"] = {**body, key: str((path.parent / body[key]).resolve())}
    if "base" not in data:
        return data
    if not isinstance(data["base"], str):
        raise ConfigError(path, "base", f"expected the path of a config to extend, got {data['base']!r}")
    base_path = (path.parent / data.pop("base")).resolve()
    if base_path in seen:
        raise ConfigError(path, "base", f"{base_path} extends itself")
    if not base_path.is_file():
        raise ConfigError(path, "base", f"{base_path}: no such config to extend")
    base = read_yaml(base_path, (*seen, path.resolve()))
    if not isinstance(base, Mapping):
        raise ConfigError(base_path, "", "expected a mapping")
    return _merge({k: v for k, v in base.items() if k != "name"}, data)
