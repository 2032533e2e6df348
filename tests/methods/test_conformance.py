"""The conformance suite: every method of the registry (canfdi.methods), the test-only one
included, against the Diagnoser protocol (canfdi.core.protocol), each both bare and wrapped in
the noise watchdog as the monitor runs it (canfdi.core.watched: a Diagnoser too).

- the block path gives exactly the streaming path's events and residuals, chunk by chunk,
  with lost samples and lost values;
- reset() restores the first run exactly (and equals a freshly built diagnoser);
- events are well formed (kinds, channels, estimates, sample order, JSON) and the example's
  fault is detected and diagnosed;
- `noise_scale` is what the normalised residuals are divided by;
- wrapped, a drive noisier than configured is said so and diagnosed, the same whatever
  the chunks;
- a bad option of the method's section is named, with the nearest valid names.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import json
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import yaml

from canfdi import methods
from canfdi.config import parse_config
from canfdi.core import kernel
from canfdi.core.protocol import MODES, Diagnoser, Supervisor
from canfdi.core.records import Compensation, FaultEvent, Sample
from canfdi.core.settings import ConfigError
from canfdi.core.watched import NoiseWatched
from tests.conftest import REPO
from tests.methods.conftest import Example

BUILT_IN = {"parity", "output_error", "uio"}
WATCHDOG_KINDS = ("mismatch", "quiet", "matched")


@pytest.fixture(params=["bare", "watched"])
def wrap(request) -> str:
    """How the diagnoser runs: as the method builds it, or wrapped in the noise watchdog."""
    return request.param


def _stream(dg: Diagnoser, ex: Example) -> tuple[list[FaultEvent], np.ndarray, np.ndarray]:
    """update() sample by sample: (events, residuals (N, m), statistics (N, m))."""
    events, rows, stats = [], [], []
    m = len(dg.residual_names)
    for i in range(len(ex.k)):
        events += dg.update(Sample(k=int(ex.k[i]), timestamp_ns=int(ex.t_ns[i]), u=ex.U[i],
                                   z=ex.Z[i]))
        rows.append(np.full(m, np.nan) if dg.last_residuals is None else dg.last_residuals)
        stats.append(np.array(dg.statistics, dtype=float))
    return events, np.array(rows), np.array(stats)


def _blocks(dg: Diagnoser, ex: Example, cuts: list[int]):
    """update_block() over the run cut at ``cuts``."""
    events, rows, stats = [], [], []
    bounds = [0, *cuts, len(ex.k)]
    for a, b in itertools.pairwise(bounds):
        res = dg.update_block(ex.k[a:b], ex.t_ns[a:b], ex.U[a:b], ex.Z[a:b])
        events += res.events
        rows.append(res.residuals)
        stats.append(res.statistic)
    return events, np.vstack(rows), np.vstack(stats)


def _same(a: np.ndarray, b: np.ndarray, what: str) -> None:
    """Equal up to rounding (the block forms sum in another order: cumulative sums, matrix
    products over a sliding window), with the same missing (NaN) entries."""
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=what)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9, err_msg=what)


def _same_events(a: list, b: list, what: str, rel: float = 1e-9) -> None:
    """The same events (kinds, samples, channels, onsets: the decisions) with the same
    estimates and variances up to rounding (a refinement's fit sums a block's samples in
    another order than one at a time)."""
    def plain(e):
        return dataclasses.replace(e, estimates={}, variances={})

    assert [plain(e) for e in a] == [plain(e) for e in b], what
    for x, y in zip(a, b, strict=True):
        for got, want in ((x.estimates, y.estimates), (x.variances, y.variances)):
            assert set(got) == set(want), what
            for key in got:
                assert got[key] == pytest.approx(want[key], rel=rel, abs=1e-12), what


def _build(ex: Example, wrap: str = "bare", kernel_name: str = "python") -> Diagnoser:
    dg = kernel.get(kernel_name).use_on(methods.get(ex.method).build(ex.config))
    if wrap == "bare":
        return dg
    # The check waits for a window with a verdict up to the longest diagnosis: the example's
    # lost commands leave output_error's residuals without one for most blocks, so the check
    # ends at that cap, here 1500 samples in, inside the example's run (3000).
    w = ex.config.watchdog
    return NoiseWatched(dg, w.factor, w.block, w.blocks, longest_diagnosis=2 * w.block)


def test_the_registry_holds_the_built_in_methods_and_the_test_one():
    assert BUILT_IN | {"tiny"} <= set(methods.names())
    for name in methods.names():
        assert methods.get(name).name == name


def test_an_unknown_method_is_named_with_the_nearest_ones():
    with pytest.raises(ConfigError) as info:
        methods.get("partiy")
    assert info.value.field == "method"
    assert "did you mean parity" in str(info.value) and "uio" in str(info.value)


def test_it_satisfies_the_protocol(example: Example, wrap: str):
    dg = _build(example, wrap)
    assert isinstance(dg, Diagnoser)
    assert isinstance(dg, Supervisor) == (wrap == "watched")
    m = len(dg.residual_names)
    assert m > 0 and len(set(dg.residual_names)) == m
    assert np.shape(dg.thresholds) == (m,) and np.all(np.asarray(dg.thresholds) > 0)
    assert np.shape(dg.statistics) == (m,)
    assert dg.mode in MODES and list(dg.compensation) == [] and dg.events == []
    np.testing.assert_array_equal(dg.noise_scale, np.ones(m))
    dg.thresholds = np.asarray(dg.thresholds) * 2.0  # settable (soak's sensitivity check)
    assert np.allclose(dg.thresholds, 2.0 * np.asarray(_build(example).thresholds))


def test_the_block_path_equals_the_streaming_path_chunk_by_chunk(example: Example, wrap: str):
    events, rows, stats = _stream(_build(example, wrap), example)
    n = len(example.k)
    for cuts in ([], [1, 8, 9, 100, 101, n // 2], list(range(37, n, 37))):
        b_events, b_rows, b_stats = _blocks(_build(example, wrap), example, cuts)
        _same_events(b_events, events, f"chunks cut at {cuts[:6]}...")
        _same(b_rows, rows, f"residuals, chunks cut at {cuts[:6]}...")
        _same(b_stats, stats, f"statistics, chunks cut at {cuts[:6]}...")


@pytest.mark.c
def test_the_c_kernel_gives_the_numpy_kernels_events_residuals_and_statistics(
        example: Example, wrap: str):
    """The same run on both kernels, in uneven chunks: the same decisions (events, their
    samples, channels and onsets), residual and statistic rows equal to 1e-12 of each
    column's magnitude (the C residuals sum a row in their own order, numpy's BLAS in its:
    a residual near zero, a difference of large terms, differs in its last bits of those),
    estimates to 1e-12 relative."""
    n = len(example.k)
    for cuts in ([1, 8, 9, 100, 101, n // 2],):  # (whole blocks: the unit tests' cases)
        ref = _blocks(_build(example, wrap), example, cuts)
        got = _blocks(_build(example, wrap, "c"), example, cuts)
        what = f"c kernel, chunks cut at {cuts}"
        _same_events(got[0], ref[0], what, rel=1e-12)
        for a, b, name in ((got[1], ref[1], "residuals"), (got[2], ref[2], "statistics")):
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=name)
            scale = np.nanmax(np.abs(b), axis=0, initial=1e-300)
            off = np.nan_to_num(np.abs(a - b)) / scale
            assert off.max(initial=0.0) <= 1e-12, f"{what}: {name} off by {off.max():.3g}"


def test_reset_restores_the_first_run_exactly(example: Example, wrap: str):
    dg = _build(example, wrap)
    first = _blocks(dg, example, [len(example.k) // 3])
    assert dg.events == first[0] and first[0]  # the run raised events to forget
    dg.reset()
    assert dg.events == [] and list(dg.compensation) == [] and dg.mode == "monitor"
    again = _blocks(dg, example, [len(example.k) // 3])
    fresh = _blocks(_build(example, wrap), example, [len(example.k) // 3])
    for run in (again, fresh):
        assert run[0] == first[0]
        np.testing.assert_array_equal(run[1], first[1])
        np.testing.assert_array_equal(run[2], first[2])


def test_a_copy_runs_apart_from_its_original(example: Example, wrap: str):
    """The watchdog's undo copies the diagnoser mid-run: the copy must go on exactly as the
    original would, and running it must leave the original as it was."""
    cut = len(example.k) // 3
    dg = _build(example, wrap)
    half = slice(0, cut)
    dg.update_block(example.k[half], example.t_ns[half], example.U[half], example.Z[half])
    twin = copy.deepcopy(dg)
    rest = slice(cut, None)
    got = twin.update_block(example.k[rest], example.t_ns[rest], example.U[rest], example.Z[rest])
    assert twin.events != dg.events  # the copy went on: the fault is in the rest
    ours = dg.update_block(example.k[rest], example.t_ns[rest], example.U[rest], example.Z[rest])
    _same_events(ours.events, got.events, "the original after its copy ran")
    _same(ours.normalized, got.normalized, "normalised residuals of the original and its copy")


def test_events_are_well_formed_and_the_fault_is_diagnosed(example: Example, wrap: str):
    dg = _build(example, wrap)
    events, _, _ = _blocks(dg, example, [])
    cfg = example.config
    names = {"actuator": cfg.inputs, "sensor": cfg.outputs}
    keys = {"actuator": ({"eta", "lambda"}, {"lambda"}), "sensor": ({"bias"},)}
    times = dict(zip(example.k.tolist(), example.t_ns.tolist(), strict=True))
    previous = -math.inf
    for e in events:
        assert e.kind in ("detected", "named", "accepted", "refined", "unexplained")
        assert e.sample >= previous and e.timestamp_ns == times[e.sample]
        previous = e.sample
        json.dumps(e.as_dict())  # the JSON contract of replay --json and the log
        if e.kind == "detected":
            assert e.residuals and set(e.residuals) <= set(dg.residual_names)
            assert e.detected_sample == e.sample
        elif e.kind == "named":  # the component, before its form or size is known
            assert e.target in names and names[e.target][e.index] == e.name
            assert e.undecided and set(e.undecided) <= {"form", "size"}
            assert e.onset_sample <= e.detected_sample < e.sample
            assert all(math.isfinite(v) for v in e.estimates.values())
        elif e.kind == "refined":  # an accepted fault's updated size
            assert (e.target, e.index) in {(a.target, a.index) for a in events
                                           if a.kind == "accepted" and a.sample <= e.sample}
            assert all(math.isfinite(v) for v in e.estimates.values())
        elif e.kind == "accepted":
            assert e.target in names and names[e.target][e.index] == e.name
            assert set(e.estimates) in keys[e.target]
            assert set(e.variances) == set(e.estimates)
            assert all(math.isfinite(v) for v in e.estimates.values())
            assert e.onset_sample <= e.detected_sample <= e.accepted_sample == e.sample
        else:
            assert e.detected_sample is not None and e.detected_sample <= e.sample
    # Every accepted fault is compensated, in order (a refinement adds to its channel's).
    accepted = [e for e in events if e.kind == "accepted"]
    channels = list(dict.fromkeys((c.target, c.index) for c in dg.compensation))
    assert channels == list(dict.fromkeys((e.target, e.index) for e in accepted))
    assert all(isinstance(c, Compensation) for c in dg.compensation)
    # The injected bias on sensor 0 (40 noise stds) is detected and diagnosed (within a few
    # samples, or once the residuals a lost command blinded are back: output_error's taint).
    detected = [e for e in events if e.kind == "detected"
                and example.fault_sample <= e.sample <= example.fault_sample + 100]
    assert detected, "the fault was not detected within 100 samples"
    diagnosed = [e for e in accepted if e.detected_sample == detected[0].sample]
    assert diagnosed, "the fault's detection ended without an accepted fault"
    assert (diagnosed[0].target, diagnosed[0].index) == ("sensor", 0)
    assert diagnosed[0].estimates["bias"] == pytest.approx(example.fault_size, rel=0.1)


def test_the_normalised_residuals_are_divided_by_the_noise_scale(example: Example):
    plain, wide = _build(example), _build(example)
    wide.noise_scale = 2.0
    n = example.fault_sample - 100  # healthy samples
    got = [dg.update_block(example.k[:n], example.t_ns[:n], example.U[:n], example.Z[:n])
           for dg in (plain, wide)]
    np.testing.assert_array_equal(wide.noise_scale, np.full(len(plain.residual_names), 2.0))
    # Up to the first event of either (a detection changes what follows).
    first = min([n] + [int(np.searchsorted(example.k, e.sample)) for r in got
                       for e in r.events])
    assert first > 200
    _same(got[1].residuals[:first], got[0].residuals[:first], "residuals")
    _same(2.0 * got[1].normalized[:first], got[0].normalized[:first], "normalised residuals")


def _configured_noise(ex: Example) -> np.ndarray:
    """(q,) the measurement noise std the example's config says."""
    std = ex.config.design.measurement_std
    assert std is not None, f"{ex.path.name} says no measurement noise"
    return np.asarray(std, dtype=float)


@pytest.mark.slow  # output_error in 37-sample chunks: over a minute
def test_wrapped_a_noisier_drive_is_said_and_diagnosed_the_same_whatever_the_chunks(
        example: Example):
    """The drive twice as noisy as configured from the start: the watchdog's check says so
    before anything is diagnosed, and the diagnoser then diagnoses the kept samples and the
    rest against the noise found, with the same events, residuals and statistics one sample
    at a time or in blocks of any size."""
    noisy = dataclasses.replace(example, Z=example.Z + np.random.default_rng(5).standard_normal(
        example.Z.shape) * np.sqrt(3.0) * _configured_noise(example))
    names = _build(noisy).residual_names
    events, rows, stats = _stream(_build(noisy, "watched"), noisy)
    said = [e for e in events if e.kind in WATCHDOG_KINDS]
    assert said and said[0].kind == "mismatch" and events[0] == said[0]
    assert set(said[0].residuals) <= set(names)
    assert all(v > noisy.config.watchdog.factor for v in said[0].estimates.values())
    n = len(noisy.k)
    for cuts in ([], [1, 8, 9, 100, 101, n // 2], list(range(37, n, 37))):
        b_events, b_rows, b_stats = _blocks(_build(noisy, "watched"), noisy, cuts)
        _same_events(b_events, events, f"chunks cut at {cuts[:6]}...")
        _same(b_rows, rows, f"residuals, chunks cut at {cuts[:6]}...")
        _same(b_stats, stats, f"statistics, chunks cut at {cuts[:6]}...")


def _with_option(example: Example, key: str, value) -> dict:
    doc = yaml.safe_load(yaml.safe_dump(example.document))
    section = methods.get(example.method).section
    doc.setdefault(section, {})
    doc[section] = dict(doc[section] or {}, **{key: value})
    return doc


def test_a_bad_option_is_named_with_the_nearest_valid_ones(example: Example):
    method = methods.get(example.method)
    assert method.section, "every method names the config section of its options"
    doc = example.document.get(method.section) or {}
    known = next(iter(doc), None)
    typo = (known[:-1] + known[-1].upper()) if known else "bogus_option"
    with pytest.raises(ConfigError) as info:
        parse_config(_with_option(example, typo, 1), example.path)
    assert info.value.field == f"{method.section}.{typo}"
    assert "unknown key" in str(info.value)
    if known:
        assert f"did you mean {known}" in str(info.value)
    if known is not None and not isinstance(doc[known], list | dict):
        with pytest.raises(ConfigError) as info:
            parse_config(_with_option(example, known, "not a number"), example.path)
        assert info.value.field == f"{method.section}.{known}"


def test_a_method_from_an_entry_point_is_found(tmp_path):
    """A package adds a method the way python-can finds interfaces: an entry point in the
    group canfdi.methods. A fresh interpreter with such a distribution on its path sees it."""
    pkg = tmp_path / "canfdi_extra"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(textwrap.dedent("""
        from tests.methods.tiny_method import METHOD as _tiny
        from dataclasses import replace
        METHOD = replace(_tiny, name="extra")
    """))
    info = tmp_path / "canfdi_extra-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: canfdi-extra\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[canfdi.methods]\nextra = canfdi_extra:METHOD\n")
    code = textwrap.dedent("""
        import sys
        from canfdi import methods
        from canfdi.config import load_config
        assert "extra" in methods.names(), methods.names()
        print(methods.get("extra").summary)
    """)
    env = {"PYTHONPATH": f"{tmp_path}:{REPO}", "PATH": "/usr/bin:/bin"}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "test-only" in res.stdout
