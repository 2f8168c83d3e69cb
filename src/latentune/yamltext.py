"""YAML text as data, with numbers in exponent form read as numbers.

PyYAML follows YAML 1.1, whose float needs a dot and a signed exponent: it reads ``1e-4``,
``1E3``, ``5e+2`` and ``1.0e6`` as text. :func:`load` reads them as floats (YAML 1.2 and JSON
do); everything else is :func:`yaml.safe_load`'s. :func:`load_arg` reads a ``--system-arg``
value: any number with a point or an exponent (``-.5`` too) is a float and a date or timestamp
(``2020-01-01``) is its text, inside lists and mappings too. This module owns numbers in exponent
form: user YAML files (spaces, reality profiles, robot specs) are read with :func:`load`; a value
already read as text is a number by :func:`exponent_float`, or by :func:`decimal_float` as
:func:`load_arg` reads it.
"""
from __future__ import annotations

import re
from typing import Any

import yaml


_MANTISSA = r"[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)"
"""A number's digits with an optional point (``1``, ``2.5``, ``1.``, ``.5``, ``1_000``)."""
_EXPONENT = re.compile(_MANTISSA + r"[eE][-+]?[0-9]+")
"""A number in exponent form: ``1e-4``, ``1E3``, ``5e+2``, ``1.0e6``, ``.5e1``."""
_POINTED = re.compile(r"(?=[^.eE]*[.eE])" + _MANTISSA + r"(?:[eE][-+]?[0-9]+)?")
"""A number in decimal or exponent form with a point or an exponent: ``2.5``, ``-.5``, ``1.``,
``1e9``, ``-2.5E+3`` (not ``10``)."""


def exponent_float(value: Any) -> Any:
    """``value``, or the float of a text in exponent form (``"1e-3"``, ``" 1.0E6 "``: what
    YAML 1.1 leaves as text); any other value (numbers, other text) as it is."""
    if isinstance(value, str) and _EXPONENT.fullmatch(value.strip()):
        return float(value.strip().replace("_", ""))
    return value


def decimal_float(text: str) -> float | None:
    """``text`` as a float if it is a number in decimal or exponent form with a point or an
    exponent (``2.5``, ``1e9``, ``1e-3``, ``-2.5E+3``; ``1e999`` is inf), else None (``10``,
    ``inf``, ``abc``). Surrounding blanks are ignored."""
    t = text.strip()
    return float(t.replace("_", "")) if _POINTED.fullmatch(t) else None


class ExponentLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that also resolves a plain scalar in exponent form to a float, and
    refuses a mapping that gives a key twice (``yaml.constructor.ConstructorError`` whose first
    line names the key and its lines), where ``yaml.safe_load`` keeps the last one. Keys that a
    merge (``<<: *anchor``) brings in may still be overridden."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[tuple[str, str], int] = {}
        for key_node, _ in node.value:
            if not isinstance(key_node, yaml.ScalarNode) or key_node.tag.endswith(":merge"):
                continue
            key = (key_node.tag, key_node.value)
            line = key_node.start_mark.line + 1
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"the key {key_node.value} is given twice (lines {seen[key]} "
                    f"and {line}): keep one")
            seen[key] = line
        return super().construct_mapping(node, deep=deep)


ExponentLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(f"^(?:{_EXPONENT.pattern})$"), list("-+0123456789."))


def problem(exc: yaml.YAMLError | UnicodeDecodeError) -> str:
    """One line saying what is wrong in a YAML text ``exc`` was raised for: PyYAML's problem
    and where (``expected ',' or ']', but got ':' at line 2, column 4``), without the context
    lines and source excerpts its own report spreads over several lines; for a file that is
    not UTF-8 text, where its first bad byte is."""
    if isinstance(exc, UnicodeDecodeError):
        return f"not UTF-8 text: {exc.reason} at byte {exc.start}"
    what = getattr(exc, "problem", None)
    if not what:
        return (str(exc).splitlines() or [type(exc).__name__])[0]
    mark = getattr(exc, "problem_mark", None)
    return what if mark is None else f"{what} at line {mark.line + 1}, column {mark.column + 1}"


def load(text: str) -> Any:
    """The data of a YAML (or JSON) text, as ``yaml.safe_load`` gives it except that
    exponent-form numbers (``1e-4``, ``1.0e6``) are floats and a key given twice in one mapping
    is refused; raises ``yaml.YAMLError``."""
    return yaml.load(text, Loader=ExponentLoader)


class ArgLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that resolves a plain scalar :func:`decimal_float` reads (a number
    with a point or an exponent) to a float and leaves dates and timestamps as their text."""


ArgLoader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag != "tag:yaml.org,2002:timestamp"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
ArgLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(f"^(?:{_POINTED.pattern})$"), list("-+0123456789."))


def load_arg(text: str) -> Any:
    """The data of a YAML text (a ``--system-arg`` value) as ``yaml.safe_load`` gives it,
    except that, alone or inside a list or mapping, a number in decimal or exponent form with
    a point or an exponent (``1e9``, ``1e-3``, ``-.5``; ``1e999`` is inf) is a float, as
    :func:`decimal_float` reads it, and a date or timestamp (``2020-01-01``,
    ``2001-12-14 21:59:43.10 -5``) a string with its text; raises ``yaml.YAMLError``."""
    return yaml.load(text, Loader=ArgLoader)
