"""The asv benchmarks (benchmarks/hot_paths.py) run: every class, every parameter, once, on
small data, so that they do not rot between the times someone runs asv."""

from __future__ import annotations

import inspect
import itertools

import pytest

from benchmarks import hot_paths


def _cases():
    for name, cls in inspect.getmembers(hot_paths, inspect.isclass):
        if cls.__module__ != hot_paths.__name__:
            continue
        params = getattr(cls, "params", None)
        grid = ([()] if params is None else
                [(p,) for p in params] if not isinstance(params[0], tuple | list)
                else list(itertools.product(*params)))
        for args in grid:
            yield pytest.param(cls, args, id=f"{name}{list(args) if args else ''}")


@pytest.mark.parametrize(("cls", "args"), list(_cases()))
def test_each_benchmark_runs(cls, args, monkeypatch):
    monkeypatch.setattr(hot_paths, "FRAMES", 3_000)
    monkeypatch.setattr(hot_paths, "SAMPLES", 500)
    bench = cls()
    bench.setup(*args)
    timed = [m for n, m in inspect.getmembers(bench, inspect.ismethod) if n.startswith("time_")]
    assert timed
    for method in timed:
        method(*args)
    if hasattr(bench, "teardown"):
        bench.teardown(*args)
