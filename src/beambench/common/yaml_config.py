"""One way to read a YAML configuration file into a pydantic model, with caps and one-line errors.

Used by protocol and rig files (:mod:`beambench.acquisition.protocol.schema`), sweep files (:mod:`beambench.studies.sweep.run`)
and beam parameter sets (:mod:`beambench.sim.models.params`). What it guarantees, whatever the file holds:

* a bounded cost: the file is at most :data:`MAX_FILE_BYTES`; nesting at most :data:`MAX_DEPTH` deep (checked on
  the event stream, which is not recursive, before anything is built); at most :data:`MAX_NODES` values once
  aliases are expanded (an alias bomb is refused before it is expanded);
* one error class, :class:`ConfigError`, whose message is one line naming the file, the field, the value
  (shortened to :data:`MAX_SHOWN` characters) and the reason;
* no Python objects: ``yaml.safe_load`` semantics (the C loader when available).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from beambench.common.errors import BeambenchError
from beambench.common.inputs import read_input_bytes

MAX_FILE_BYTES = 1 << 20  # 1 MiB: the largest shipped configuration is ~2 kB
MAX_DEPTH = 32  # nested mappings/lists
MAX_NODES = 100_000  # values after alias expansion
MAX_SHOWN = 80  # characters of a value shown in an error

_SafeLoader: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class DuplicateKeyError(yaml.constructor.ConstructorError):
    """A mapping names the same key twice (YAML 1.2 forbids it; PyYAML would keep the later value silently)."""


class _Loader(_SafeLoader):
    """Safe loading, plus YAML 1.2 floats: ``26.0e6`` and ``1e-4`` are numbers (YAML 1.1 needs ``1.0e-4``),
    and a key given twice in one mapping is an error (a second ``limits:`` block must not replace the first)."""

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        if isinstance(node, yaml.MappingNode):
            # literal keys only, before merge keys (``<<: *base``) are flattened in: those may be overridden
            seen: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:  # an unhashable key: the base class says so
                    break
                if first is not None:
                    raise DuplicateKeyError(
                        None, None, f"duplicate key {shorten(key, 40)} (first on line {first})", key_node.start_mark
                    )
                seen[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)
_Parse: Any = yaml.CParser if hasattr(yaml, "CParser") else yaml.SafeLoader  # event source for the caps pass

M = TypeVar("M", bound=BaseModel)


class _Missing:
    def __repr__(self) -> str:
        return "<missing>"


MISSING: Any = _Missing()


def shorten(value: Any, limit: int = MAX_SHOWN) -> str:
    """``repr(value)`` cut to ``limit`` characters; never builds the repr of a huge container in full."""
    if isinstance(value, (list, tuple, dict, set)) and len(value) > limit:
        kind = type(value).__name__
        return f"<{kind} of {len(value)} items>"
    try:
        text = _bounded_repr(value, limit + 1)
    except RecursionError:
        text = f"<deeply nested {type(value).__name__}>"
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _bounded_repr(value: Any, budget: int, depth: int = 0) -> str:
    """A repr that stops once ``budget`` characters are produced (shared aliases make full reprs explode)."""
    if depth > 8:
        return "…"
    if isinstance(value, dict):
        parts, used = [], 2
        for k, v in value.items():
            part = f"{_bounded_repr(k, budget, depth + 1)}: {_bounded_repr(v, budget, depth + 1)}"
            parts.append(part)
            used += len(part) + 2
            if used > budget:
                break
        return "{" + ", ".join(parts) + "}"
    if isinstance(value, (list, tuple)):
        parts, used = [], 2
        for v in value:
            part = _bounded_repr(v, budget, depth + 1)
            parts.append(part)
            used += len(part) + 2
            if used > budget:
                break
        return "[" + ", ".join(parts) + "]"
    if isinstance(value, str) and len(value) > budget:
        return repr(value[:budget])
    return repr(value)


class ConfigError(BeambenchError, ValueError):
    """A configuration file (or option) is invalid. ``str()`` is one line: file, field, value, reason.

    ``ConfigError("a preformatted one-line message")`` is also accepted (``field``/``reason`` then empty).
    """

    def __init__(self, file: str, field: str | None = None, value: Any = MISSING, reason: str | None = None) -> None:
        self.file, self.value = file, value
        self.field, self.reason = field or "", reason or ""
        if field is None and reason is None:
            super().__init__(_one_line(file))
            return
        shown = "" if value is MISSING else f" = {shorten(value)}"
        super().__init__(_one_line(f"{file}: {field}{shown}: {reason}"))


def _one_line(text: str) -> str:
    line = " ".join(text.split())
    return line if len(line) <= 600 else line[:599] + "…"


# --- reading ---------------------------------------------------------------------------------------------
def read_text(path: str | Path, error: type[ConfigError] = ConfigError) -> str:
    """The file's text, refusing files over :data:`MAX_FILE_BYTES`, unreadable files and non-UTF-8 bytes."""
    p = Path(path)

    def refuse(message: str) -> ConfigError:  # check_input_file's one line, as this module's error
        return error(str(p), "(file)", MISSING, message.removeprefix(f"{p}: "))

    try:
        raw = read_input_bytes(p, "configuration file", MAX_FILE_BYTES, refuse)  # kind and size before any read
    except OSError as exc:
        raise error(str(p), "(file)", MISSING, exc.strerror or str(exc)) from None
    if len(raw) > MAX_FILE_BYTES:
        raise error(str(p), "(file)", MISSING, f"larger than {MAX_FILE_BYTES // 1024} KiB: not a configuration file")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(str(p), "(file)", MISSING, f"not a text file (byte {exc.start} is not UTF-8)") from None


def parse_yaml(text: str, file: str, error: type[ConfigError] = ConfigError) -> Any:
    """``yaml.safe_load`` of ``text`` within the caps; YAML errors become one-line :class:`ConfigError`."""
    if len(text.encode("utf-8", "surrogatepass")) > MAX_FILE_BYTES:
        raise error(file, "(file)", MISSING, f"larger than {MAX_FILE_BYTES // 1024} KiB: not a configuration file")
    if "\x00" in text:
        raise error(file, "(file)", MISSING, "not a text file (contains NUL bytes)")
    try:
        _check_shape(text, file, error)
        return yaml.load(text, Loader=_Loader)  # a safe loader (CSafeLoader or SafeLoader)
    except DuplicateKeyError as exc:
        where = f"line {exc.problem_mark.line + 1}" if exc.problem_mark is not None else "(file)"
        raise error(file, where, MISSING, f"{exc.problem}: a key may be given once") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "(file)"
        problem = getattr(exc, "problem", None) or str(exc)
        raise error(file, where, MISSING, f"not valid YAML ({_one_line(str(problem))[:200]})") from None
    except RecursionError:  # belt and braces: _check_shape bounds the depth first
        raise error(file, "(file)", MISSING, f"nested deeper than {MAX_DEPTH} levels") from None


def _check_shape(text: str, file: str, error: type[ConfigError]) -> None:
    """Depth and expanded size from the event stream (flat, not recursive), before any object is built."""
    depth = 0
    # expanded size of each anchored node, and a stack of [anchor, size so far] of the open collections
    anchored: dict[str, int] = {}
    stack: list[list[Any]] = [[None, 0]]
    total = 0
    for ev in yaml.parse(text, Loader=_Parse):
        if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            depth += 1
            if depth > MAX_DEPTH:
                raise error(file, "(file)", MISSING, f"nested deeper than {MAX_DEPTH} levels")
            stack.append([ev.anchor, 1])
            total += 1
        elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            depth -= 1
            anchor, size = stack.pop()
            if anchor is not None:
                anchored[anchor] = size
            stack[-1][1] += size
        elif isinstance(ev, (yaml.ScalarEvent, yaml.AliasEvent)):
            size = 1 if isinstance(ev, yaml.ScalarEvent) else anchored.get(str(ev.anchor), 1)
            if isinstance(ev, yaml.ScalarEvent) and ev.anchor is not None:
                anchored[ev.anchor] = 1
            stack[-1][1] += size
            total += size
            if size > MAX_NODES or total > MAX_NODES:
                raise error(file, "(file)", MISSING, f"expands to more than {MAX_NODES} values (YAML aliases?)")


def load_yaml_file(path: str | Path, error: type[ConfigError] = ConfigError) -> tuple[Any, str]:
    """(parsed data, text) of a YAML file within the caps."""
    text = read_text(path, error)
    return parse_yaml(text, str(path), error), text


# --- validating ------------------------------------------------------------------------------------------
def _is_tag(part: Any) -> bool:
    """A pydantic location entry that names a validator or a union branch (``list[float]``, ``Range``)."""
    text = str(part)
    return isinstance(part, str) and (text.startswith("function-") or "[" in text or text[:1].isupper())


def _walk(data: Any, loc: tuple[Any, ...]) -> tuple[list[Any], Any]:
    """The data's own path along ``loc`` and the value there (:data:`MISSING` past a missing key). An entry that
    is a key (or index) of the data is part of the path, even one that looks like a tag (a user's ``Tip``
    marker); one that is not is a missing field where the data is a mapping and it does not look like a tag,
    otherwise a tag (``str`` under a list value, ``Range`` under a mapping)."""
    path: list[Any] = []
    for key in loc:
        if data is not MISSING:
            try:
                data = data[key]
                path.append(key)
                continue
            except (KeyError, IndexError, TypeError):
                if _is_tag(key) or not isinstance(data, dict):
                    continue
        elif _is_tag(key):
            continue
        data = MISSING
        path.append(key)
    return path, data


def field_path(loc: tuple[Any, ...], data: Any = MISSING) -> str:
    """``sweep.frequencies.0`` from a pydantic error location in ``data`` (validator and union-branch entries
    dropped)."""
    return ".".join(str(p) for p in _walk(data, loc)[0]) or "(top level)"


def lookup(data: Any, loc: tuple[Any, ...]) -> Any:
    """The value at ``loc`` in ``data``, or :data:`MISSING`."""
    return _walk(data, loc)[1]


def _reason(err: dict[str, Any]) -> str:
    if err["type"] == "extra_forbidden":
        return "unknown field"
    if err["type"] == "finite_number":
        return "must be a finite number (not NaN or infinity)"
    msg = str(err["msg"]).removeprefix("Value error, ")
    if err["type"] in ("float_type", "int_type") and isinstance(err.get("input"), bool):
        return f"{msg} (true/false is not a number)"
    return msg


def validate(
    model: type[M],
    data: Any,
    file: str,
    error: type[ConfigError] = ConfigError,
    what: str = "fields",
    context: dict[str, Any] | None = None,
) -> M:
    """``model.model_validate(data)``; the first problem as a one-line :class:`ConfigError` (file, field, value)."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise error(file, "(top level)", MISSING, f"expected a mapping of {what}")
    try:
        return model.model_validate(data, context=context)
    except ValidationError as exc:
        errors = exc.errors()
        # in a union, a branch's "wrong type" hides the real problem of the branch the value was meant for
        err = next((e for e in errors if not str(e["type"]).endswith("_type")), errors[0])
        loc = tuple(err["loc"])
        raise error(file, field_path(loc, data), lookup(data, loc), _reason(dict(err))) from None
    except RecursionError:
        raise error(file, "(file)", MISSING, f"nested deeper than {MAX_DEPTH} levels") from None


def load_model(
    path: str | Path, model: type[M], error: type[ConfigError] = ConfigError, what: str = "fields"
) -> tuple[M, str]:
    """Read, cap, parse and validate a YAML file into ``model``; returns the model and the file's text."""
    data, text = load_yaml_file(path, error)
    return validate(model, data, str(path), error, what), text
