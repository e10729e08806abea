"""Shared by the numpy reference scripts: where the test vectors go, and the
deterministic noise generator the C++ tests reproduce operation for operation
(tests/analysis/reference_data.h)."""

import math
import os

import numpy as np

GAMMA = 0x9E3779B97F4A7C15
SQRT3 = math.sqrt(3.0)

OUT_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "tests",
                       "analysis", "data")


def splitmix64(seed, count):
    """Draws 1..count of the counter-based splitmix64 stream of `seed`."""
    i = np.arange(1, count + 1, dtype=np.uint64)
    with np.errstate(over="ignore"):
        z = np.uint64(seed) + i * np.uint64(GAMMA)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return z


def noise(seed, count, sigma):
    """`count` approximately normal values of std `sigma` (sum of 4 uniforms)."""
    u = (splitmix64(seed, 4 * count) >> np.uint64(11)).astype(np.float64) * 2.0**-53
    u = u.reshape(count, 4)
    s = ((u[:, 0] + u[:, 1]) + u[:, 2]) + u[:, 3]
    return sigma * SQRT3 * (s - 2.0)
