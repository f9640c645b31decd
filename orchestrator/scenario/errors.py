"""Scenario errors: one line per problem, naming the file, the key path and what was expected."""

from __future__ import annotations

import difflib
from typing import Any

from pydantic import BaseModel, Tag

from node_runtime.model.arrival import KIND_ERROR, KINDS
from node_runtime.model.mobility import MODEL_ERROR


class ScenarioError(ValueError):
    """A scenario the user must fix; ``errors`` holds one line per problem."""

    def __init__(self, errors: list[str]) -> None:
        super().__init__("\n".join(errors))
        self.errors = errors


def error_path(err: dict[str, Any]) -> str:
    """The key path of a validation error: an arrival's unknown ``kind`` is named as that key."""
    loc = err["loc"]
    if err["type"] == KIND_ERROR and isinstance(err.get("input"), dict):
        loc = (*loc, "kind")
    elif err["type"] == MODEL_ERROR and isinstance(err.get("input"), dict):
        loc = (*loc, "model")
    return key_path(loc)


def key_path(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if _is_tag(part):
            continue
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


_EXPECT = {
    "missing": "required key is missing",
    "int_type": "expected an integer",
    "int_parsing": "expected an integer",
    "int_from_float": "expected an integer",
    "float_type": "expected a number",
    "float_parsing": "expected a number",
    "finite_number": "expected a finite number",
    "bool_type": "expected true or false",
    "bool_parsing": "expected true or false",
    "string_type": "expected a string",
    "dict_type": "expected a mapping",
    "model_type": "expected a mapping",
    "model_attributes_type": "expected a mapping",
    "list_type": "expected a list",
    "tuple_type": "expected a list",
}


def _is_tag(part: Any) -> bool:
    """A tag pydantic puts in an error's location for the alternative of a union it tried ("<number>"):
    not a key of the file."""
    return isinstance(part, str) and part.startswith("<") and part.endswith(">")


def describe(err: dict[str, Any], model: type[BaseModel]) -> str:
    kind = err["type"]
    if err["loc"] and err["loc"][-1] == "<number>" and kind in ("float_type", "float_parsing"):
        return f"expected a number, or a range {{low, high, grace}} (got {err.get('input')!r})"
    ctx = err.get("ctx", {})
    got = err.get("input")
    if kind == KIND_ERROR:
        if not isinstance(got, dict):
            return f"expected a mapping (got {got!r})"
        *first, last = map(repr, KINDS)
        return f"expected {', '.join(first)} or {last} (got {got.get('kind')!r})"
    if kind == MODEL_ERROR:
        if not isinstance(got, dict):
            return f"expected a mapping with a model (got {got!r})"
        return f"{err['msg']} (got {got.get('model')!r})"
    if kind == "extra_forbidden":
        field = str(err["loc"][-1])
        known = _fields_at(model, err["loc"][:-1])
        hint = difflib.get_close_matches(field, known, n=1)
        return "unknown key" + (f" (did you mean '{hint[0]}'?)" if hint else
                                f"; expected one of: {', '.join(sorted(known))}" if known else "")
    if kind in ("greater_than", "greater_than_equal", "less_than_equal", "less_than"):
        op = {"greater_than": ">", "greater_than_equal": ">=", "less_than_equal": "<=", "less_than": "<"}[kind]
        bound = next(iter(ctx.values()))
        return f"expected a number {op} {bound if isinstance(bound, int) else format(bound, 'g')} (got {got!r})"
    if kind == "literal_error":
        return f"expected {ctx.get('expected')} (got {got!r})"
    if kind == "too_short":
        return f"expected at least {ctx.get('min_length')} item(s)"
    if kind in ("too_long", "tuple_length"):
        return f"expected {ctx.get('max_length', 2)} items (got {got!r})"
    if kind == "value_error":
        return str(ctx.get("error", err["msg"]))
    if kind in _EXPECT:
        return _EXPECT[kind] + ("" if kind == "missing" else f" (got {got!r})")
    return err["msg"][0].lower() + err["msg"][1:]


def _fields_at(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """Field names of the model found at ``loc`` (for 'did you mean' hints). Parts that are not
    fields are mapping keys (a profile's name) and keep the current model."""
    current: Any = model
    annotation: Any = None
    for part in loc:
        if _is_tag(part):  # the alternative of a union that was tried: that alternative's fields
            current = _inner_model(annotation, part) or current
            continue
        fields = getattr(current, "model_fields", {})
        if isinstance(part, str) and part in fields:
            annotation = fields[part].annotation
            current = _inner_model(annotation)
    return list(getattr(current, "model_fields", {}))


def _inner_model(annotation: Any, tag: str | None = None) -> Any:
    """The first model in ``annotation`` (or, given a tag, the one the union's alternative of that tag holds)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    tags = [m.tag for m in getattr(annotation, "__metadata__", ()) if isinstance(m, Tag)]
    if tag is not None and tags:
        return _inner_model(annotation.__origin__) if tag in tags else None
    for arg in getattr(annotation, "__args__", ()):
        found = _inner_model(arg, tag)
        if found is not None:
            return found
    return None


