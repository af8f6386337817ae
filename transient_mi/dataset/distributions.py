"""Seeded random draws for dataset parameters (``random:`` in a spec).

A distribution is written in the spec as a mapping with exactly one
distribution key and optional modifiers::

    rotation_deg: {uniform: [-30, 30]}            # float in [low, high)
    bin_width_ps: {loguniform: [20, 200], round: 1}
    t0_ps:        {normal: [10000, 200]}          # mean, standard deviation
    n_bins:       {randint: [40, 60]}             # integer, both ends included
    pose:         {choice: [arms_down, t_pose], weights: [3, 1]}

``round: k`` rounds a float draw to ``k`` decimals (``round: 0`` gives an
integer). Draws come from a :class:`numpy.random.Generator` that the caller
seeds per item, so the same spec and seed give the same values.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np

from transient_core.errors import UserInputError

#: Distribution names and what their argument list means.
DISTRIBUTIONS: dict[str, str] = {
    "uniform": "[low, high]: float, low <= x < high",
    "loguniform": "[low, high]: float with log(x) uniform, 0 < low <= x < high",
    "normal": "[mean, std]: float, Gaussian, std > 0",
    "randint": "[low, high]: integer, low <= x <= high (both included)",
    "choice": "[v1, v2, ...]: one of the listed values (optional weights: [w1, w2, ...])",
}
_MODIFIERS = ("round", "weights")


def _is_number(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(float(v))


def _is_int(v: Any) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


@dataclass(frozen=True)
class Distribution:
    """One parsed distribution (see the module docstring for the spec syntax).

    Attributes
    ----------
    kind : str
        One of :data:`DISTRIBUTIONS`.
    args : tuple
        ``(low, high)``, ``(mean, std)`` or the choices.
    weights : tuple of float or None
        Normalised probabilities of the choices (``choice`` only).
    round : int or None
        Decimals kept of a float draw.
    """

    kind: str
    args: tuple
    weights: tuple | None = None
    round: int | None = None

    @classmethod
    def parse(cls, where: str, spec: Any) -> "Distribution":
        """Parse the spec entry ``where`` (used in messages, e.g. ``random.t0_ps``).

        Raises
        ------
        UserInputError
            For anything but one known distribution with valid arguments.
        """
        allowed = ", ".join(DISTRIBUTIONS)
        if not isinstance(spec, dict):
            raise UserInputError(f"{where}: {spec!r} is not a distribution; write e.g. "
                                 f"{{uniform: [0, 1]}} (allowed: {allowed})")
        kinds = [k for k in spec if k in DISTRIBUTIONS]
        unknown = [k for k in spec if k not in DISTRIBUTIONS and k not in _MODIFIERS]
        if unknown:
            raise UserInputError(f"{where}: unknown key {unknown[0]!r}; allowed: one of {allowed}, "
                                 f"plus {', '.join(_MODIFIERS)}")
        if len(kinds) != 1:
            raise UserInputError(f"{where}: give exactly one distribution (got {len(kinds)}: "
                                 f"{', '.join(kinds) or 'none'}); allowed: {allowed}")
        kind = kinds[0]
        args = spec[kind]
        if not isinstance(args, (list, tuple)):
            raise UserInputError(f"{where}.{kind}: {args!r} is not a list; expected {DISTRIBUTIONS[kind]}")
        args = tuple(args)
        weights = None
        rnd = spec.get("round")
        if "weights" in spec and kind != "choice":
            raise UserInputError(f"{where}: weights apply to choice only, not {kind}")
        if rnd is not None:
            if kind in ("choice", "randint"):
                raise UserInputError(f"{where}: round applies to uniform, loguniform and normal, not {kind}")
            if not _is_int(rnd) or not 0 <= rnd <= 15:
                raise UserInputError(f"{where}.round: {rnd!r}; expected an integer number of decimals, 0 to 15")
            rnd = int(rnd)
        if kind == "choice":
            if len(args) == 0:
                raise UserInputError(f"{where}.choice: empty list; give at least one value")
            for v in args:
                if isinstance(v, (dict, list)) and not (isinstance(v, list) and all(_is_number(x) for x in v)):
                    raise UserInputError(f"{where}.choice: {v!r} is not a value (number, string, "
                                         "boolean or list of numbers)")
            if "weights" in spec:
                w = spec["weights"]
                if (not isinstance(w, (list, tuple)) or len(w) != len(args) or not all(_is_number(x) for x in w)
                        or any(x < 0 for x in w) or sum(w) <= 0):
                    raise UserInputError(f"{where}.weights: {w!r}; expected {len(args)} numbers >= 0 "
                                         "(one per choice) with a positive sum")
                s = float(sum(w))
                weights = tuple(float(x) / s for x in w)
            return cls(kind, args, weights, None)
        if len(args) != 2 or not all(_is_number(a) for a in args):
            raise UserInputError(f"{where}.{kind}: {list(args)!r}; expected two finite numbers "
                                 f"{DISTRIBUTIONS[kind]}")
        a, b = args
        if kind == "uniform" and not a < b:
            raise UserInputError(f"{where}.uniform: [{a!r}, {b!r}] is an empty range; need low < high")
        if kind == "loguniform" and not 0 < a < b:
            raise UserInputError(f"{where}.loguniform: [{a!r}, {b!r}]; need 0 < low < high")
        if kind == "normal" and not b > 0:
            raise UserInputError(f"{where}.normal: std={b!r}; need std > 0")
        if kind == "randint":
            if not (_is_int(a) and _is_int(b)):
                raise UserInputError(f"{where}.randint: [{a!r}, {b!r}]; bounds must be integers")
            if not a <= b:
                raise UserInputError(f"{where}.randint: [{a!r}, {b!r}] is an empty range; need low <= high")
            args = (int(a), int(b))
        else:
            args = (float(a), float(b))
        return cls(kind, args, None, rnd)

    def _finish(self, x: float) -> Any:
        x = float(x)
        if self.round is None:
            return x
        return int(round(x)) if self.round == 0 else round(x, self.round)

    def draw(self, rng: np.random.Generator) -> Any:
        """One value (Python int, float, str, bool or list), drawn from ``rng``."""
        if self.kind == "choice":
            i = int(rng.choice(len(self.args), p=self.weights))
            return self.args[i]
        a, b = self.args
        if self.kind == "uniform":
            return self._finish(rng.uniform(a, b))
        if self.kind == "loguniform":
            return self._finish(math.exp(rng.uniform(math.log(a), math.log(b))))
        if self.kind == "normal":
            return self._finish(rng.normal(a, b))
        if self.kind == "randint":
            return int(rng.integers(a, b, endpoint=True))
        raise AssertionError(self.kind)  # pragma: no cover

    def probe_values(self) -> list:
        """Values worth validating before work: the ends of a range, or every choice.

        (A normal distribution has no ends: its mean +- 3 std are probed.)
        """
        if self.kind == "choice":
            return list(self.args)
        a, b = self.args
        if self.kind == "normal":
            return [self._finish(a - 3 * b), self._finish(a + 3 * b)]
        if self.kind == "randint":
            return [a, b]
        return [self._finish(a), self._finish(b)]

    def to_spec(self) -> dict:
        """The spec mapping this was parsed from (normalised)."""
        d: dict[str, Any] = {self.kind: list(self.args)}
        if self.weights is not None:
            d["weights"] = list(self.weights)
        if self.round is not None:
            d["round"] = self.round
        return d
