"""Reading YAML inputs, bounded, and turning validation errors into one line: the part of scene loading that
every config reader shares (scene files, dataset configs, detector presets, tal configs), kept free of the scene's
meshes and kernels so that readers of configs stay light (:mod:`datagen.scene.load` re-exports it)."""
from __future__ import annotations

import reprlib
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from ..errors import DatagenError, SceneError

MAX_SHOWN = 80
"""Characters of an offending value an error message shows (a 1e6-element list stays one short line)."""

MAX_PROBLEMS = 5
"""Validation problems listed in one error message (the count of the others follows)."""


def short_repr(value: Any, limit: int = MAX_SHOWN) -> str:
    """``repr(value)`` cut to ``limit`` characters (``…`` marks a cut), on one line."""
    shorter = reprlib.Repr()
    shorter.maxlist = shorter.maxtuple = shorter.maxdict = 8
    shorter.maxstring = shorter.maxother = limit
    text = " ".join(shorter.repr(value).split())
    return text if len(text) <= limit else text[:limit - 1] + "…"


def format_validation_error(exc: ValidationError, source: str | None = None, head: str | None = None) -> str:
    """One line: ``file: head.field.path: message (got value)`` per problem (at most :data:`MAX_PROBLEMS`,
    values cut by :func:`short_repr`), joined by "; "."""
    lines = []
    errors = exc.errors()
    for err in errors[:MAX_PROBLEMS]:
        loc = ".".join(([head] if head else []) + [str(p) for p in err["loc"]])
        value = err.get("input")
        shown = "" if isinstance(value, dict) else f" (got {short_repr(value)})"
        msg = " ".join(str(err["msg"]).split()).removeprefix("Value error, ")[:300]
        lines.append(f"{source + ': ' if source else ''}{loc + ': ' if loc else ''}{msg}{shown}")
    if len(errors) > MAX_PROBLEMS:
        lines.append(f"and {len(errors) - MAX_PROBLEMS} more problem(s)")
    return "; ".join(lines)


MAX_YAML_BYTES = 8 << 20
"""Largest YAML input read, bytes (8 MiB): scenes, configs and presets are a few kB; meshes live in their own
files."""

MAX_YAML_VALUES = 1_000_000
"""Largest number of values a YAML document may expand to, an alias counting its anchor's values again at
every use: bounds the memory and time an alias bomb ("billion laughs") can take; real inputs hold hundreds."""


def read_yaml(path: Path, what: str, error: type[DatagenError] = SceneError) -> Any:
    """Parsed content of the YAML file ``path`` (a ``what``: "scene file", "tal config", ...), bounded in size
    (:data:`MAX_YAML_BYTES`) and in alias expansion (:data:`MAX_YAML_VALUES`). ``error`` is the class raised: a
    scene's :class:`SceneError`, a config reader's :class:`~datagen.errors.ConfigError` (docs/reliability.md).

    Raises:
        ``error`` (SceneError by default): the file does not exist ("<what> not found: <path>"), is too large,
            is not UTF-8 text, is not valid YAML or expands beyond the bound (each names the file, in one line).
    """
    path = Path(path)
    if not path.is_file():
        raise error(f"{what} not found: {path}")
    size = path.stat().st_size
    if size > MAX_YAML_BYTES:
        raise error(f"{path}: {size} bytes is too large for a {what} (at most {MAX_YAML_BYTES} bytes)")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a UTF-8 text file (byte {exc.start}): is it really a {what}?") from None
    return parse_yaml(text, str(path), error)


class DuplicateKeyError(yaml.constructor.ConstructorError):
    """A YAML mapping holds the same key twice (raised by :class:`UniqueKeyLoader`)."""


class UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a mapping that holds the same key twice at any depth (plain PyYAML keeps
    the last one silently: a second top-level ``simulation:`` would replace the first). Keys merged in by
    ``<<: *anchor`` may be overridden, as YAML's merge key intends; only keys written in the mapping itself
    count."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.setdefault(key, key_node)
                except TypeError:   # an unhashable key: the base class reports it
                    continue
                if first is not key_node:
                    raise DuplicateKeyError(
                        None, None, f"duplicate key {short_repr(key)} on lines {first.start_mark.line + 1} "
                        f"and {key_node.start_mark.line + 1} (the second would silently replace the first)")
        return super().construct_mapping(node, deep=deep)


def parse_yaml(text: str, source: str, error: type[DatagenError] = SceneError) -> Any:
    """Parse YAML ``text`` with :class:`UniqueKeyLoader` (the safe loader, refusing duplicate keys), then refuse
    documents that expand to more than :data:`MAX_YAML_VALUES` values (aliases counted at every use, recursive
    aliases included). ``error`` is the class raised (as in :func:`read_yaml`).

    Raises:
        ``error`` (SceneError by default): invalid YAML, a key repeated in one mapping ("<source>: duplicate
            key 'simulation' on lines 12 and 30 ...") or too large an expansion; one short line naming ``source``.
    """
    if len(text) > MAX_YAML_BYTES:
        raise error(f"{source}: {len(text)} characters is too large (at most {MAX_YAML_BYTES})")
    try:
        data = yaml.load(text, Loader=UniqueKeyLoader)   # noqa: S506 - a SafeLoader subclass
    except DuplicateKeyError as exc:
        raise error(f"{source}: {exc.problem}") from None
    except yaml.YAMLError as exc:
        raise error(f"{source}: not valid YAML: {' '.join(str(exc).split())[:300]}") from None
    except RecursionError:
        raise error(f"{source}: YAML nested too deeply") from None
    count, stack = 0, [data]
    while stack:
        value = stack.pop()
        count += 1
        if count > MAX_YAML_VALUES:
            raise error(f"{source}: the YAML expands to more than {MAX_YAML_VALUES} values (its aliases "
                        "repeat their anchors' content): not a datagen input")
        if isinstance(value, dict):
            stack.extend(value.keys())
            stack.extend(value.values())
        elif isinstance(value, (list, tuple)):
            stack.extend(value)
    return data
