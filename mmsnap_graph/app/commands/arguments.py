"""argparse types shared by the sub-commands: ``NAME=VALUES`` options (a
node name and its numbers, e.g. a pose ``S2=0,7,180``)."""

from __future__ import annotations

import argparse
from typing import Callable

import numpy as np

__all__ = ["named_values", "named_pose", "solver_choice"]


def named_values(kind: str, n_values: int | None) -> Callable[[str], tuple[str, object]]:
    """argparse type for ``NAME=V1,V2,...`` with ``n_values`` numbers ->
    ``(name, [floats])``; ``n_values`` None: one string value -> ``(name,
    str)``. ``kind`` names the values in the error (``X_M,Y_M,PHI_DEG``)."""
    def parse(text: str):
        name, sep, rest = text.partition("=")
        if not sep or not name or not rest:
            raise argparse.ArgumentTypeError(f"{text!r} must look like NAME={kind}")
        if n_values is None:
            return name, rest
        try:
            values = [float(v) for v in rest.split(",")]
        except ValueError:
            values = []
        if len(values) != n_values:
            raise argparse.ArgumentTypeError(f"{text!r} must look like NAME={kind}")
        return name, values
    return parse


def named_pose(text: str) -> tuple[str, list[float]]:
    """argparse type for a node pose ``NAME=X_M,Y_M,PHI_DEG`` -> ``(name,
    [x_m, y_m, phi_rad])`` (degrees on the command line, radians inside)."""
    name, (x, y, phi_deg) = named_values("X_M,Y_M,PHI_DEG (e.g. S2=0,7,180)", 3)(text)
    return name, [x, y, float(np.deg2rad(phi_deg))]


def solver_choice(allowed: tuple[str, ...]) -> Callable[[str], str]:
    """argparse type for ``--solver``: one of ``allowed`` (names of
    :data:`mmsnap_graph.fusion.solvers.settings.SOLVERS`); a former name
    (``batch``, ``numpy``) is refused naming the one that replaced it."""
    def parse(text: str) -> str:
        from mmsnap_graph.errors import ValidationError
        from mmsnap_graph.fusion.solvers.settings import check_solver

        try:
            return check_solver(text, allowed, what="--solver")
        except ValidationError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    parse.__name__ = "solver"
    return parse
