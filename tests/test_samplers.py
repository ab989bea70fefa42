"""Tests for cellsim.config.sampling: campaign samplers and per-run draws."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsim.config.sampling import (
    ChoiceSampler,
    Sampler,
    SimplexSampler,
    UniformSampler,
    draw_configuration,
    run_seed,
    sample,
)
from cellsim.config.typed_yaml import ConfigError, load_text

WAITS = [f"operator.waypoints.{w}.wait" for w in ("bench_entrance", "bench", "cell_entrance", "cell", "exit")]
POINTS = {
    "operator_waits": WAITS,
    "range_thresholds": ["range_detector.near_below", "range_detector.close_below"],
    "speeds": ["operator.speed"],
}
SAMPLERS: dict[str, Sampler] = {
    "operator_waits": SimplexSampler("simplex", total=20.0, minimum=0.5),
    "range_thresholds": UniformSampler("uniform", low=0.5, high=1.5),
    "speeds": ChoiceSampler("choice", values=[1.0, 1.4, 1.8]),
}

seeds = st.integers(0, 2**32 - 1)
micro = st.integers(0, 10**8).map(lambda k: k / 1_000_000)  # values on the 1e-6 grid
FAST = settings(max_examples=60, deadline=None)


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


# --------------------------------------------------------------------------- properties


@FAST
@given(low=st.floats(-1e6, 1e6), width=st.floats(1e-6, 1e6), n=st.integers(1, 8), seed=seeds)
def test_uniform_within_bounds(low, width, n, seed):
    s = UniformSampler("uniform", low, low + width)
    values = sample(s, n, rng(seed))
    assert len(values) == n
    assert all(type(v) is float and s.low <= v <= s.high for v in values)


@FAST
@given(values=st.lists(st.one_of(st.booleans(), st.integers(-5, 5), st.floats(-10, 10), st.text(max_size=4)),
                       min_size=1, max_size=6, unique_by=lambda v: (type(v), v)),
       n=st.integers(1, 8), seed=seeds)
def test_choice_yields_only_given_values(values, n, seed):
    drawn = sample(ChoiceSampler("choice", values), n, rng(seed))
    assert len(drawn) == n
    assert all(any(type(d) is type(v) and d == v for v in values) for d in drawn)
    json.dumps(drawn)


@FAST
@given(total=micro.filter(lambda t: t > 0), fraction=st.floats(0, 1), n=st.integers(1, 8), seed=seeds)
def test_simplex_sums_to_total_and_respects_minimum(total, fraction, n, seed):
    minimum = math.floor(total / n * fraction * 1_000_000) / 1_000_000  # n * minimum <= total
    values = sample(SimplexSampler("simplex", total, minimum), n, rng(seed))
    assert len(values) == n
    assert abs(math.fsum(values) - total) <= 1e-9
    assert all(type(v) is float and v >= minimum for v in values)
    assert all(round(v, 6) == v for v in values)  # on the 1e-6 grid


def test_simplex_paper_test_vector():
    values = sample(SimplexSampler("simplex", 20.0), 5, rng(3))
    assert abs(sum(values) - 20.0) <= 1e-9 and all(v >= 0 for v in values)
    assert sample(SimplexSampler("simplex", 20.0, minimum=4.0), 5, rng(3)) == [4.0] * 5
    assert sample(SimplexSampler("simplex", 20.0, minimum=0.5), 1, rng(3)) == [20.0]


@pytest.mark.parametrize("n", [1, 2, 5, 8])
def test_simplex_is_unbiased(n):
    s = SimplexSampler("simplex", total=20.0, minimum=0.5)
    g = rng(n)
    draws = np.array([sample(s, n, g) for _ in range(2000)])
    assert np.allclose(draws.mean(axis=0), 20.0 / n, rtol=0.05)


@FAST
@given(seed=seeds, index=st.integers(0, 10**6))
def test_draw_configuration_is_deterministic(seed, index):
    config = draw_configuration(SAMPLERS, POINTS, seed, index)
    assert config == draw_configuration(SAMPLERS, POINTS, seed, index)
    assert set(config) == {p for paths in POINTS.values() for p in paths}
    json.dumps(config)


def test_run_config_independent_of_which_runs_are_drawn():
    all_runs = [draw_configuration(SAMPLERS, POINTS, 7, i) for i in range(10)]
    assert draw_configuration(SAMPLERS, POINTS, 7, 5) == all_runs[5]
    assert [draw_configuration(SAMPLERS, POINTS, 7, i) for i in reversed(range(10))][::-1] == all_runs


def test_different_indices_and_seeds_give_different_configurations():
    configs = [draw_configuration(SAMPLERS, POINTS, 7, i) for i in range(50)]
    waits = {tuple(c[p] for p in WAITS) for c in configs}
    assert len(waits) == 50
    assert draw_configuration(SAMPLERS, POINTS, 8, 0) != configs[0]


def test_only_sampled_points_appear():
    config = draw_configuration({"speeds": SAMPLERS["speeds"]}, POINTS, 1, 0)
    assert list(config) == ["operator.speed"]


def test_run_seed():
    seeds_ = [run_seed(42, i) for i in range(10_000)]
    assert len(set(seeds_)) == len(seeds_)
    assert all(type(s) is int and 0 <= s < 2**31 for s in seeds_)
    assert seeds_ == [run_seed(42, i) for i in range(10_000)]
    assert run_seed(43, 0) != run_seed(42, 0)


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize("make, words", [
    (lambda: UniformSampler("uniform", 1.5, 0.5), ["high", "greater than low"]),
    (lambda: UniformSampler("uniform", 1.0, 1.0), ["high", "greater than low"]),
    (lambda: UniformSampler("uniform", 0.0, math.inf), ["high", "finite"]),
    (lambda: ChoiceSampler("choice", []), ["values", "at least one"]),
    (lambda: ChoiceSampler("choice", [1, 2, 1]), ["values.2", "twice"]),
    (lambda: SimplexSampler("simplex", 0.0), ["total", "positive"]),
    (lambda: SimplexSampler("simplex", 20.0, -1.0), ["minimum", "non-negative"]),
    (lambda: SimplexSampler("simplex", 20.0, 21.0), ["minimum", "exceed total"]),
    (lambda: SimplexSampler("simplex", 20.0000001), ["total", "multiple of 1e-06"]),
])
def test_config_errors(make, words):
    with pytest.raises(ValueError) as info:
        make()
    assert all(w in str(info.value) for w in words), str(info.value)


def test_simplex_minimums_exceeding_total():
    with pytest.raises(ValueError, match=r"5 paths x minimum 4\.5 = 22\.5 exceeds total 20\.0"):
        sample(SimplexSampler("simplex", 20.0, 4.5), 5, rng())


def test_unknown_configuration_point():
    with pytest.raises(ValueError, match="unknown configuration point.*operator_wait;.*known: "
                                         "operator_waits, range_thresholds, speeds"):
        draw_configuration({"operator_wait": SAMPLERS["operator_waits"]}, POINTS, 0, 0)


def test_path_sampled_twice():
    points = {"a": ["x.y"], "b": ["x.y"]}
    samplers = {"a": SAMPLERS["speeds"], "b": SAMPLERS["speeds"]}
    with pytest.raises(ValueError, match="path x.y is sampled by both configuration points a and b"):
        draw_configuration(samplers, points, 0, 0)


def test_bad_counts_and_seeds():
    with pytest.raises(ValueError, match="n_paths must be at least 1"):
        sample(SAMPLERS["speeds"], 0, rng())
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        draw_configuration(SAMPLERS, POINTS, -1, 0)
    with pytest.raises(ValueError, match="index must be a non-negative integer"):
        run_seed(0, -3)


# --------------------------------------------------------------------------- YAML


@dataclass
class Campaign:
    samplers: dict[str, Sampler]


def test_yaml_picks_sampler_classes():
    text = (
        "samplers:\n"
        "  operator_waits: {kind: simplex, total: 20.0, minimum: 0.5}\n"
        "  thresholds: {kind: uniform, low: 0.5, high: 1.5}\n"
        "  mode: {kind: choice, values: [true, 3, 2.5, fast]}\n"
    )
    samplers = load_text(Campaign, text).value.samplers
    assert samplers == {
        "operator_waits": SimplexSampler("simplex", 20.0, 0.5),
        "thresholds": UniformSampler("uniform", 0.5, 1.5),
        "mode": ChoiceSampler("choice", [True, 3, 2.5, "fast"]),
    }
    assert [type(v) for v in samplers["mode"].values] == [bool, int, float, str]


def test_yaml_bad_kind_names_the_line():
    text = (
        "samplers:\n"
        "  operator_waits: {kind: simplex, total: 20.0}\n"
        "  thresholds: {kind: unifrom, low: 0.5, high: 1.5}\n"
    )
    with pytest.raises(ConfigError) as info:
        load_text(Campaign, text, "campaign.yaml")
    assert info.value.line == 3
    assert str(info.value).startswith("campaign.yaml:3: samplers.thresholds.kind: unknown kind 'unifrom'")
    assert "did you mean 'uniform'" in str(info.value)


def test_yaml_validation_error_names_the_line():
    text = "samplers:\n  thresholds:\n    kind: uniform\n    low: 2.0\n    high: 1.0\n"
    with pytest.raises(ConfigError, match=r"<text>:5: samplers.thresholds.high: must be greater than low"):
        load_text(Campaign, text)
