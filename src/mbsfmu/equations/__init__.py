"""Equations of motion M·ÿ + k = q of a compiled scene (seed 000)."""

from .evaluator import Evaluator

__all__ = ["Evaluator"]
