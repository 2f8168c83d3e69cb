"""Count phrases of the text a user reads: ``counted(1, "trial")`` is "1 trial",
``counted(2, "trial")`` "2 trials"."""
from __future__ import annotations


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and ``noun``: the noun as it is when ``n`` is 1, else its plural (``plural``, or
    ``noun`` + "s")."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"
