"""Argparse pieces every subcommand module shares: the help formatters and the checked option types."""

from __future__ import annotations

import argparse
import math

from ..sim import MAX_THREADS

__all__ = ["HelpFormatter", "TopHelpFormatter", "positive_float", "non_negative_int", "thread_count"]


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows every option's default, except where the help text already says what None means."""

    def _get_help_string(self, action: argparse.Action) -> str:
        if action.default is None:
            return action.help or ""
        return super()._get_help_string(action) or ""


class TopHelpFormatter(HelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Keeps the line breaks of the command overview."""


def positive_float(text: str) -> float:
    """A finite number above zero (durations, rates)."""
    value = float(text)
    if not (value > 0.0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def non_negative_int(text: str) -> int:
    """An integer of at least zero (seeds)."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text}")
    return value


def thread_count(text: str) -> int:
    """A number of worker threads the rollouts accept: 1 to :data:`sabre.sim.MAX_THREADS`."""
    value = int(text)
    if not 1 <= value <= MAX_THREADS:
        raise argparse.ArgumentTypeError(f"must be between 1 and {MAX_THREADS}, got {text}")
    return value
