"""Remembered designs: computed once, kept bit for bit in the store, never trusted when
damaged, and a store that cannot be written is no error."""

import numpy as np
import pytest
from canfdi.configs import CONFIG_DIR

from canfdi.config import load_config
from canfdi.core import memo
from canfdi.io.memostore import DirectoryStore, cache_directory
from canfdi.methods.parity import thresholds
from canfdi.monitor import Monitor


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    """A process memory of its own, and a store in tmp_path (uninstalled after)."""
    monkeypatch.setattr(memo, "_memory", {})
    store = DirectoryStore(tmp_path / "cache")
    memo.install(store)
    yield store
    memo.install(None)


def test_a_result_is_kept_in_the_store_and_read_back_exactly(fresh, monkeypatch):
    value = np.array([1 / 3, 2.5e-300, -7.0])
    key = memo.digest("t", np.arange(3.0))
    assert np.array_equal(memo.remembered(key, lambda: value, (3,)), value)
    assert (fresh.directory / f"{key}.json").is_file()
    monkeypatch.setattr(memo, "_memory", {})  # a new process: memory empty, the store kept
    again = memo.remembered(key, lambda: pytest.fail("recomputed"), (3,))
    assert again.tobytes() == value.tobytes()


@pytest.mark.parametrize("damage", ["", "not json", "[1, 2]", '["0x1p0", "0x1p1"]', "{}"])
def test_a_damaged_or_wrong_entry_is_recomputed_and_replaced(fresh, damage):
    key = memo.digest("d", damage)
    fresh.directory.mkdir(parents=True)
    (fresh.directory / f"{key}.json").write_text(damage)
    value = np.array([4.0, 5.0, 6.0])
    assert np.array_equal(memo.remembered(key, lambda: value, (3,)), value)
    assert memo._decode((fresh.directory / f"{key}.json").read_text(), (3,)) is not None


def test_a_store_that_cannot_be_written_only_costs_the_computation(monkeypatch, tmp_path):
    monkeypatch.setattr(memo, "_memory", {})
    blocked = tmp_path / "file"
    blocked.write_text("")
    memo.install(DirectoryStore(blocked / "cache"))  # under a file: mkdir fails
    try:
        key = memo.digest("u")
        assert memo.remembered(key, lambda: np.ones(2), (2,)).tolist() == [1.0, 1.0]
    finally:
        memo.install(None)


def test_the_parity_thresholds_of_a_restarted_monitor_come_from_the_store(fresh, monkeypatch):
    config = load_config(CONFIG_DIR / "dc_motor.yaml")
    first = Monitor(config).diagnoser.thresholds.copy()
    assert len(list(fresh.directory.glob("*.json"))) == 1
    monkeypatch.setattr(memo, "_memory", {})
    monkeypatch.setattr(thresholds, "_calibrate",
                        lambda *a, **k: pytest.fail("calibrated again"))
    second = Monitor(config).diagnoser.thresholds
    assert second.tobytes() == first.tobytes()


def test_the_cache_directory_follows_canfdi_then_systemd_then_xdg_then_home():
    assert cache_directory({"CANFDI_CACHE_DIR": "/a", "CACHE_DIRECTORY": "/b"}).as_posix() == "/a"
    assert cache_directory({"CACHE_DIRECTORY": "/b:/c", "HOME": "/h"}).as_posix() == "/b"
    assert cache_directory({"XDG_CACHE_HOME": "/x", "HOME": "/h"}).as_posix() == "/x/canfdi"
    assert cache_directory({"HOME": "/h"}).as_posix() == "/h/.cache/canfdi"
    assert cache_directory({}) is None
