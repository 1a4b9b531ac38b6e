"""The contract the three solvers of :mod:`mmsnap_graph.fusion.solvers` share
(no GTSAM here):

- :data:`SOLVERS`: one name per solver, the same in every entry point and in
  the CLI -- ``"gtsam"`` (:mod:`.gtsam_graph`), ``"vectorized"``
  (:mod:`.vectorized`, numpy over many frames) and ``"scalar"``
  (:mod:`.scalar`, plain floats, one frame at a time); :func:`check_solver`;
- :class:`LevenbergMarquardtSettings`: the damping and stopping rules of
  Levenberg-Marquardt, read by the hand-written solvers (:mod:`.scalar`,
  :mod:`.vectorized_lm`, the calibration pre-solve) and mirrored into GTSAM's
  ``LevenbergMarquardtParams`` (:func:`.gtsam_graph.lm_params`), so that
  every solver damps, updates and gives up alike;
- (what every solver returns is one record,
  :class:`~mmsnap_graph.data.solution.FusionSolution`, through
  :func:`mmsnap_graph.fusion.solve.solve`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ...errors import ValidationError

__all__ = [
    "SOLVERS",
    "check_solver",
    "LevenbergMarquardtSettings",
    "LM_SETTINGS",
]

#: The solvers of the one-frame problem, by the one name each has everywhere.
SOLVERS = ("gtsam", "vectorized", "scalar")

#: Names the solvers had before; :func:`check_solver` names the new one.
_FORMER_NAMES = {"batch": "vectorized", "numpy": "scalar"}


def check_solver(solver: object, allowed: tuple[str, ...] = SOLVERS, *,
                 what: str = "solver") -> str:
    """``solver`` if it is one of ``allowed`` (a subset of :data:`SOLVERS`);
    ValidationError otherwise, naming the allowed names (and, for a former
    name such as ``"batch"`` or ``"numpy"``, the one that replaced it)."""
    if isinstance(solver, str) and solver in allowed:
        return solver
    names = " or ".join(map(repr, allowed))
    hint = ""
    if solver in _FORMER_NAMES:
        hint = f" ({solver!r} is now called {_FORMER_NAMES[solver]!r})"
    raise ValidationError(f"{what} must be {names}, got {solver!r}{hint}")


@dataclass(frozen=True, kw_only=True, slots=True)
class LevenbergMarquardtSettings:
    """Levenberg-Marquardt's damping and stopping rules (GTSAM's
    ``LevenbergMarquardtOptimizer`` with Marquardt's diagonal damping and
    Nielsen's damping update).

    A step solves ``(H + lambda D) d = -g`` with ``D`` the diagonal of ``H``
    clamped to ``[min_diagonal, max_diagonal]``. An accepted step (the cost
    falls and the model fidelity, actual over predicted decrease, exceeds
    ``min_model_fidelity``) multiplies lambda by ``max(1/3, 1 - (2 rho -
    1)^3)`` (not below ``lambda_min``) and resets the factor to 2; a rejected
    one multiplies lambda by the factor (``lambda_factor`` at first) and
    doubles the factor; at ``lambda_max`` the solver gives up searching (the
    cost cannot fall: a minimum to rounding). It stops when an iteration
    lowers the cost by at most ``relative_tolerance`` of it or by at most
    ``absolute_tolerance``, or after ``max_iterations`` iterations (then a
    failure, :attr:`~mmsnap_graph.data.results.Status.MAX_ITERATIONS`).

    The vectorized solver (:mod:`.vectorized_lm`) damps alike but stops on
    the size of its steps (``FusionOptions.step_tolerance``) and counts steps,
    rejected ones included: its limit is ``max_steps`` (an iteration of GTSAM
    and of the scalar solver may try several damping values, so the two
    limits are not the same number).

    The defaults converge to rounding: the solvers must agree to 1e-6 of a
    standard deviation, and Gauss-Newton's quadratic convergence makes the
    last steps cheap. ``lambda_initial``, ``lambda_factor`` and
    ``lambda_max`` are GTSAM's defaults.
    """

    lambda_initial: float = 1e-5
    lambda_factor: float = 10.0
    lambda_min: float = 0.0
    lambda_max: float = 1e5
    min_model_fidelity: float = 1e-3
    min_diagonal: float = 1e-6
    max_diagonal: float = 1e32
    relative_tolerance: float = 1e-14
    absolute_tolerance: float = 1e-14
    max_iterations: int = 500
    max_steps: int = 200

    def __post_init__(self) -> None:
        for name in ("lambda_initial", "lambda_max", "min_diagonal", "max_diagonal",
                     "relative_tolerance", "absolute_tolerance"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not (math.isfinite(value) and value > 0):
                raise ValidationError(f"{name} must be a positive finite number, got {value!r}")
        for name in ("lambda_min", "min_model_fidelity"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not (math.isfinite(value) and value >= 0):
                raise ValidationError(f"{name} must be a finite number >= 0, got {value!r}")
        if isinstance(self.lambda_factor, bool) or not isinstance(self.lambda_factor, (int, float)) \
                or not (math.isfinite(self.lambda_factor) and self.lambda_factor > 1):
            raise ValidationError(f"lambda_factor must be a finite number > 1, "
                                  f"got {self.lambda_factor!r}")
        if not self.lambda_min <= self.lambda_initial < self.lambda_max:
            raise ValidationError(
                "need lambda_min <= lambda_initial < lambda_max, got "
                f"{self.lambda_min!r}, {self.lambda_initial!r}, {self.lambda_max!r}")
        if not self.min_diagonal <= self.max_diagonal:
            raise ValidationError(f"need min_diagonal <= max_diagonal, got "
                                  f"{self.min_diagonal!r} > {self.max_diagonal!r}")
        for name in ("max_iterations", "max_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValidationError(f"{name} must be an integer >= 1, got {value!r}")

    def damping_update(self, rho: float) -> float:
        """Nielsen's factor on lambda after a step accepted with model
        fidelity ``rho``: ``max(1/3, 1 - (2 rho - 1)^3)``."""
        t = 2.0 * rho - 1.0  # a product, not **: inf instead of OverflowError
        return max(1.0 / 3.0, 1.0 - t * t * t)


#: The settings every solver uses unless told otherwise.
LM_SETTINGS = LevenbergMarquardtSettings()
