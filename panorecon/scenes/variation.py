"""A synthetic scene's free parameters: their defaults give the base scene, and a variant (``bedroom@3``) draws
them from one NumPy Generator seeded from the scene name and K (SHA-256 of the name, no global state), so a
variant is the same in every process and on every machine with the same NumPy.

Builders ask for each parameter by a unique name, in a fixed order; every value taken is recorded in ``params``
(JSON-serialisable) so a result can say what was run. Pure NumPy (no Open3D)."""

from __future__ import annotations

import hashlib

import numpy as np


def variant_rng(name: str, k: int) -> np.random.Generator:
    """The Generator of variant ``k`` of synthetic scene ``name`` (PCG64 seeded by 128 bits of SHA-256)."""
    digest = hashlib.sha256(f"panorecon-scene-variant:{name}@{k}".encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:16], "little"))


class Draws:
    """Parameters at their defaults (``rng`` None: the base scene, every value returned unchanged, so the base
    scene is bit-identical to a builder with the constants written in) or drawn from ``rng`` (a variant)."""

    def __init__(self, rng: np.random.Generator | None = None):
        self.rng = rng
        self.params: dict[str, object] = {}

    def _keep(self, name: str, value):
        if name in self.params:
            raise ValueError(f"scene parameter {name!r} is taken twice")
        self.params[name] = value.tolist() if isinstance(value, np.ndarray) else value
        return value

    def uniform(self, name: str, default: float, low: float, high: float) -> float:
        """``default``, or uniform in [low, high)."""
        return self._keep(name, default if self.rng is None else float(self.rng.uniform(low, high)))

    def integer(self, name: str, default: int, low: int, high: int) -> int:
        """``default``, or uniform over low..high inclusive."""
        return self._keep(name, default if self.rng is None else int(self.rng.integers(low, high + 1)))

    def flag(self, name: str, default: bool = False) -> bool:
        """``default``, or a fair coin."""
        return self._keep(name, default if self.rng is None else bool(self.rng.integers(2)))

    def _vary(self, color, spread: float) -> np.ndarray:
        factors = self.rng.uniform(1 - spread, 1 + spread, 3) * self.rng.uniform(1 - spread, 1 + spread)
        return np.clip(np.asarray(color, float) * factors, 0.0, 1.0)

    def color(self, name: str, default, spread: float = 0.25):
        """An RGB albedo in [0, 1]: ``default`` (returned as given), or each channel times a factor uniform in
        [1 - spread, 1 + spread] and all three by one more such factor (brightness), clipped to [0, 1]."""
        return self._keep(name, default if self.rng is None else self._vary(default, spread))

    def palette(self, name: str, default, spread: float = 0.25):
        """A list of RGB colours [N, 3], each varied as by ``color``."""
        return self._keep(name, default if self.rng is None else np.stack([self._vary(c, spread) for c in default]))

    def direction(self, name: str, default: np.ndarray, min_elevation_deg: float, max_elevation_deg: float):
        """A unit vector [3] (a light or the sun): ``default``, or uniform azimuth and an elevation above the
        horizontal uniform in [min, max] degrees."""
        if self.rng is None:
            return self._keep(name, default)
        az = self.rng.uniform(0.0, 2 * np.pi)
        el = np.radians(self.rng.uniform(min_elevation_deg, max_elevation_deg))
        return self._keep(name, np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]))
