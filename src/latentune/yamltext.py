"""YAML text as data, with numbers in exponent form read as numbers.

PyYAML follows YAML 1.1, whose float needs a dot and a signed exponent: it reads ``1e-4``,
``1E3``, ``5e+2`` and ``1.0e6`` as text. :func:`load` reads them as floats (YAML 1.2 and JSON
do); everything else is :func:`yaml.safe_load`'s. :func:`load_no_dates` reads a date or timestamp
(``2020-01-01``) as its text. This module owns numbers in exponent form: user YAML files (spaces,
reality profiles, robot specs) are read with :func:`load`; a value already read as text is a
number by :func:`exponent_float`, a ``--system-arg`` text by :func:`decimal_float`.
"""
from __future__ import annotations

import re
from typing import Any

import yaml


_MANTISSA = r"[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)"
"""A number's digits with an optional point (``1``, ``2.5``, ``1.``, ``.5``, ``1_000``)."""
_EXPONENT = re.compile(_MANTISSA + r"[eE][-+]?[0-9]+")
"""A number in exponent form: ``1e-4``, ``1E3``, ``5e+2``, ``1.0e6``, ``.5e1``."""
_DECIMAL = re.compile(_MANTISSA + r"(?:[eE][-+]?[0-9]+)?")
"""A number in decimal or exponent form: ``10``, ``2.5``, ``.5``, ``1e9``, ``-2.5E+3``."""


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
    if _DECIMAL.fullmatch(t) and not t.lstrip("+-").replace("_", "").isdigit():
        return float(t.replace("_", ""))
    return None


class ExponentLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that also resolves a plain scalar in exponent form to a float."""


ExponentLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(f"^(?:{_EXPONENT.pattern})$"), list("-+0123456789."))


def load(text: str) -> Any:
    """The data of a YAML (or JSON) text, as ``yaml.safe_load`` gives it except that
    exponent-form numbers (``1e-4``, ``1.0e6``) are floats; raises ``yaml.YAMLError``."""
    return yaml.load(text, Loader=ExponentLoader)


class NoDateLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that leaves dates and timestamps (``2020-01-01``) as their text."""


NoDateLoader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag != "tag:yaml.org,2002:timestamp"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}


def load_no_dates(text: str) -> Any:
    """The data of a YAML text as ``yaml.safe_load`` gives it, except that a date or timestamp
    (``2020-01-01``, ``2001-12-14 21:59:43.10 -5``), alone or inside a list or mapping, is a
    string with its text; raises ``yaml.YAMLError``."""
    return yaml.load(text, Loader=NoDateLoader)
