"""Argparse value types shared by every command: bounded whole numbers and finite numbers, each refusing a
bad value with one line that names the allowed range."""
from __future__ import annotations

import argparse

import numpy as np

MAX_COUNT = 1_000_000  # the largest count any flag takes (steps, runs, pings, ...)


def int_in(lo: int, hi: int, name: str = "whole number"):
    """An argparse type: a whole number from ``lo`` to ``hi``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be at least {lo} and at most {hi}, got {value}")
        return value

    parse.__name__ = name
    return parse


def float_in(lo: float, hi: float, name: str = "number"):
    """An argparse type: a finite number from ``lo`` to ``hi`` (``lo > 0``: a positive number)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not (value > 0 and np.isfinite(value)) and lo > 0:
            raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text}")
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be from {lo:g} to {hi:g}, got {text}")
        return value

    parse.__name__ = name
    return parse


positive_int = int_in(1, MAX_COUNT, "positive_int")


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0 and np.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text}")
    return value
