"""YAML text as data, with numbers in exponent form read as numbers.

PyYAML follows YAML 1.1, whose float needs a dot and a signed exponent: it reads ``1e-4``,
``1E3``, ``5e+2`` and ``1.0e6`` as text. :func:`load` reads them as floats (YAML 1.2 and JSON
do); everything else is :func:`yaml.safe_load`'s. :func:`load_no_dates` reads a date or timestamp
(``2020-01-01``) as its text.
"""
from __future__ import annotations

import re
from typing import Any

import yaml


class ExponentLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that also resolves a plain scalar in exponent form to a float."""


ExponentLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))


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
