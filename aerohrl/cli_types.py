"""Argument types shared by every command line: numbers are checked when parsed.

A bad number is then a one-line usage error (exit status 2) before anything runs or
any folder is created, in the same words everywhere: seeds are ``nonneg_int``, counts
and sizes ``positive_int``, rates and lengths ``positive_float``, weights
``nonneg_float``; ``finite_float`` only refuses NaN and inf.
"""

from __future__ import annotations

import argparse
import math
from typing import Callable


def _number(kind: type, text: str):
    try:
        v = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not {'an integer' if kind is int else 'a number'}: {text!r}") from None
    if kind is float and not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return v


def _bounded(kind: type, low, strict: bool, name: str) -> Callable[[str], int | float]:
    """A parser of ``kind`` values > ``low`` (``strict``) or >= ``low``."""

    def parse(text: str):
        v = _number(kind, text)
        if v < low or (strict and v == low):
            raise argparse.ArgumentTypeError(f"must be {'>' if strict else '>='} {low:g}, got {text}")
        return v

    parse.__name__ = name  # argparse names the type in its messages
    return parse


nonneg_int = _bounded(int, 0, False, "nonneg_int")
positive_int = _bounded(int, 1, False, "positive_int")
positive_float = _bounded(float, 0.0, True, "positive_float")
nonneg_float = _bounded(float, 0.0, False, "nonneg_float")


def finite_float(text: str) -> float:
    """A finite float (argparse type): ``nan`` and ``inf`` are refused with a one-line error."""
    return _number(float, text)


__all__ = ["nonneg_int", "positive_int", "positive_float", "nonneg_float", "finite_float"]
