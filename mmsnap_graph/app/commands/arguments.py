"""argparse types shared by the sub-commands: ``NAME=VALUES`` options (a
node name and its numbers, e.g. a pose ``S2=0,7,180``)."""

from __future__ import annotations

import argparse
import warnings
from typing import Callable

import numpy as np

from mmsnap_graph.errors import MmsnapWarning, ValidationError

__all__ = ["named_values", "named_pose", "solver_choice", "check_sigmas", "SIGMA_LIMITS",
           "HEADING_HELP", "looks_like_radians"]


#: The heading convention, stated by every option that takes a node pose.
HEADING_HELP = ("PHI is the heading in degrees: the direction of the antenna array axis (TI's "
                "x axis, along the board); the radar looks along its boresight, PHI + 90 deg "
                "(docs/CONVENTIONS.md)")


def looks_like_radians(value: float, text: str) -> bool:
    """Whether a value typed where degrees are asked looks like radians: not
    zero, not whole, within +-2 pi, and written with three decimals or more
    (``1.5708``) or within 0.01 of a multiple of pi/12 (``3.14``, ``0.785``)."""
    if value == 0 or float(value).is_integer() or abs(value) > 2 * np.pi + 0.01:
        return False
    mantissa = text.strip().lower().split("e")[0]
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    round_angle = np.min(np.abs(abs(value) - np.pi / 12 * np.arange(1, 25))) < 0.01
    return decimals >= 3 or bool(round_angle)


def named_values(kind: str, n_values: int | None,
                 degrees: tuple[int, ...] = ()) -> Callable[[str], tuple[str, object]]:
    """argparse type for ``NAME=V1,V2,...`` with ``n_values`` numbers ->
    ``(name, [floats])``; ``n_values`` None: one string value -> ``(name,
    str)``. ``kind`` names the values in the error (``X_M,Y_M,PHI_DEG``).
    ``degrees`` : the indices of values in degrees; one that looks like
    radians (:func:`looks_like_radians`) warns (:class:`MmsnapWarning`)."""
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
        names = kind.split(" ")[0].split(",")
        for k in degrees:
            if looks_like_radians(values[k], rest.split(",")[k]):
                warnings.warn(f"{text!r}: {names[k]}={values[k]:g} looks like radians "
                              f"({values[k]:g} rad = {np.degrees(values[k]):.4g} deg); this "
                              "option takes degrees", MmsnapWarning, stacklevel=2)
        return name, values
    return parse


def named_pose(text: str) -> tuple[str, list[float]]:
    """argparse type for a node pose ``NAME=X_M,Y_M,PHI_DEG`` -> ``(name,
    [x_m, y_m, phi_rad])`` (degrees on the command line, radians inside)."""
    name, (x, y, phi_deg) = named_values("X_M,Y_M,PHI_DEG (e.g. S2=0,7,180)", 3,
                                         degrees=(2,))(text)
    return name, [x, y, float(np.deg2rad(phi_deg))]


def solver_choice(allowed: tuple[str, ...]) -> Callable[[str], str]:
    """argparse type for ``--solver``: one of ``allowed`` (names of
    :data:`mmsnap_graph.fusion.solvers.settings.SOLVERS`); a former name
    (``batch``, ``numpy``) is refused naming the one that replaced it."""
    def parse(text: str) -> str:
        from mmsnap_graph.errors import MmsnapWarning, ValidationError
        from mmsnap_graph.fusion.solvers.settings import check_solver

        try:
            return check_solver(text, allowed, what="--solver")
        except ValidationError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    parse.__name__ = "solver"
    return parse


#: Largest plausible measurement sigma of each component of ``--sigmas``, and
#: the unit mistake a larger value most likely is. The spatial frequency
#: omega = pi sin(theta) lies within +-pi, so its sigma cannot exceed pi.
SIGMA_LIMITS = (
    ("range_m", 10.0, "metres: centimetres or millimetres typed?"),
    ("omega_rad", float(np.pi), "radians of the spatial frequency omega = pi sin(theta), "
                                "within +-pi: degrees typed?"),
    ("doppler_mps", 50.0, "m/s: km/h or cm/s typed?"),
)


def check_sigmas(values) -> None:
    """``--sigmas RANGE_M OMEGA_RAD DOPPLER_MPS``: three finite sigmas > 0,
    each within :data:`SIGMA_LIMITS`; else :class:`ValidationError` naming
    the flag, the component and the likely unit mistake."""
    for value, (name, limit, unit) in zip(values, SIGMA_LIMITS):
        if not (np.isfinite(value) and value > 0):
            raise ValidationError(f"--sigmas: {name} must be finite and > 0, got {value!r}")
        if value > limit:
            raise ValidationError(f"--sigmas: {name}={value:g} is more than {limit:.4g}, the "
                                  f"largest plausible sigma, in {unit}")
