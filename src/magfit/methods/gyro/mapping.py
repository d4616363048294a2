"""Stage 3's candidates: the 24 standard axis mappings of a magnetometer against the gyroscope.

A magnetometer is often mounted turned by a right angle (or soldered with its axes read in another order)
against the gyroscope. A standard mapping P (one of the 24 proper signed permutations,
:func:`magfit.rotations.signed_permutations`) makes ``G = W Pᵀ`` with W symmetric and definite (MAGYC's model in
the turned frame): 3 unknowns fewer than a general G. A field and its negative turn alike, so (1) of
:mod:`.method` cannot tell a mapping P from its mirror −P (the other 24 of the 48): the magnetometer is
taken to be right-handed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...rotations import signed_permutations


def _name(p: NDArray[np.float64]) -> str:
    """``"+x-y-z"``: the gyro axis (and its sign) each magnetometer axis x, y, z lies along."""
    words = []
    for column in range(3):
        row = int(np.argmax(np.abs(p[:, column])))
        words.append(("+" if p[row, column] > 0 else "-") + "xyz"[row])
    return "".join(words)


#: ``mapping`` names: ``"+x-y-z"`` reads "the magnetometer's x along the gyro's +x, its y along −y, its z along
#: −z" (a turn of 180° about x); the matrix M turns magnetometer vectors into the gyro's axes, ``b = M m``.
MAPPINGS: dict[str, NDArray[np.float64]] = {_name(p): p for p in signed_permutations()}


def mapping_name(matrix: ArrayLike) -> str:
    """The name in :data:`MAPPINGS` of the signed permutation nearest a rotation (gyro = matrix @ magnetometer)."""
    m = np.asarray(matrix, dtype=np.float64)
    return min(MAPPINGS, key=lambda name: float(np.linalg.norm(MAPPINGS[name] - m)))
