"""How much work a notebook or script does: the full run, or a small one for CI.

Notebooks call :func:`scaled` for every step count, episode count or trial count, so the same
code path runs everywhere; CI sets ``MARLANDER_BUDGET=small`` (d2l-style).
"""

from __future__ import annotations

import os

BUDGET_VARIABLE = "MARLANDER_BUDGET"
BUDGETS = ("full", "small")


def current() -> str:
    """``"full"`` unless the environment variable ``MARLANDER_BUDGET`` says ``"small"``."""
    value = os.environ.get(BUDGET_VARIABLE, "full").strip().lower()
    if value not in BUDGETS:
        raise ValueError(f"{BUDGET_VARIABLE}={value!r} is not allowed; use one of {BUDGETS}.")
    return value


def scaled(full: int, small: int) -> int:
    """``full`` normally, ``small`` when ``MARLANDER_BUDGET=small``."""
    return small if current() == "small" else full
