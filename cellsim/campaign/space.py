"""The search space of a scenario: its samplers' configurations as points of the unit cube.

``cellsim falsify`` searches where a campaign samples. Each sampler gives the
cube some coordinates, in the samplers' sorted name order (as
:func:`cellsim.config.sampling.draw_configuration` serves them):

* ``uniform`` over ``n`` paths: ``n`` coordinates, ``u -> low + (high - low) u``;
* ``choice`` over ``n`` paths: ``n`` coordinates, ``u`` picks value ``floor(u k)`` of ``k``;
* ``simplex`` over ``n`` paths: ``n - 1`` coordinates, the cut points of the
  remainder ``total - n * minimum`` once sorted; the values are the spacings, on
  the sampler's grid of 1e-6 exactly as it draws them.

A point drawn uniformly from the cube is therefore a configuration drawn from the
campaign's own distribution (sorted uniform cut points have flat Dirichlet
spacings), which is what makes random search through this code the campaign's
baseline. Coordinates outside ``[0, 1]`` are clipped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellsim.config.sampling import _STEPS, ChoiceSampler, Sampler, SimplexSampler, UniformSampler, _on_grid

__all__ = ["SearchSpace"]


@dataclass(frozen=True)
class _Block:
    name: str
    sampler: Sampler
    paths: tuple[str, ...]

    @property
    def size(self) -> int:
        return len(self.paths) - 1 if isinstance(self.sampler, SimplexSampler) else len(self.paths)


class SearchSpace:
    """``samplers`` (configuration point -> sampler) over ``points`` (configuration point -> paths)."""

    def __init__(self, samplers: dict[str, Sampler], points: dict[str, list[str]]):
        unknown = sorted(set(samplers) - set(points))
        if unknown:
            raise ValueError(f"unknown configuration point(s) {', '.join(unknown)}; "
                             f"known: {', '.join(sorted(points)) or 'none'}")
        self._blocks = [_Block(name, samplers[name], tuple(points[name])) for name in sorted(samplers)]
        self.dimension = sum(b.size for b in self._blocks)
        """Coordinates of a point (0 when the scenario samples nothing, or only one-path simplexes)."""

    def centre(self) -> np.ndarray:
        """The point of the middle configuration: every range's midpoint, every simplex's equal shares."""
        parts = [np.arange(1, b.size + 1) / (b.size + 1) if isinstance(b.sampler, SimplexSampler)
                 else np.full(b.size, 0.5) for b in self._blocks]
        return np.concatenate(parts) if parts else np.zeros(0)

    def decode(self, point) -> dict[str, object]:
        """The configuration (``{dotted_path: value}``) at ``point``, a sequence of ``dimension`` numbers."""
        u = np.clip(np.asarray(point, dtype=float).reshape(-1), 0.0, 1.0)
        if u.size != self.dimension:
            raise ValueError(f"a point of this space has {self.dimension} coordinates, got {u.size}")
        config: dict[str, object] = {}
        at = 0
        for block in self._blocks:
            values = _values(block, u[at:at + block.size])
            config.update(zip(block.paths, values))
            at += block.size
        return config


def _values(block: _Block, u: np.ndarray) -> list:
    s, n = block.sampler, len(block.paths)
    if isinstance(s, UniformSampler):
        return [min(s.high, max(s.low, s.low + (s.high - s.low) * float(x))) for x in u]
    if isinstance(s, ChoiceSampler):
        k = len(s.values)
        return [s.values[min(int(x * k), k - 1)] for x in u]
    total, minimum = _on_grid("total", s.total), _on_grid("minimum", s.minimum)
    remainder = total - n * minimum
    if remainder < 0:
        raise ValueError(f"simplex sampler {block.name}: {n} paths x minimum {s.minimum} exceeds total {s.total}")
    ends = np.floor(remainder * np.sort(u)).astype(np.int64)
    shares = np.diff(np.append(ends, remainder), prepend=0)
    return [(minimum + int(k)) / _STEPS for k in shares]
