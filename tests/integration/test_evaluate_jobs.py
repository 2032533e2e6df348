"""`canfdi evaluate --jobs N | --scheduler ADDRESS`: the Monte Carlo runs spread over Dask
workers give exactly the serial run's results for the same seed (2 workers, a small --runs);
a scheduler that is not there is one line and exit status 2."""

from __future__ import annotations

import contextlib
import io
import json
import logging

import pytest

from tests.cli import canfdi_main as main

pytest.importorskip("distributed")

pytestmark = pytest.mark.slow

ARGS = ["evaluate", "--plant", "dc_motor", "--runs", "5", "--seed", "7", "--json",
        "--no-progress"]


def evaluate(*extra: str) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main([*ARGS, *extra]) == 0
    result = json.loads(out.getvalue())
    result.pop("wall_s")  # the only figure that is not the diagnosis's
    return result


def test_two_workers_give_the_serial_results():
    from distributed import LocalCluster

    serial = evaluate()
    assert serial["faults"] > 0 and len(serial["fault_list"]) == serial["faults"]
    assert evaluate("--jobs", "2") == serial
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster:
        assert evaluate("--scheduler", cluster.scheduler_address) == serial


def test_no_scheduler_there_is_one_line_and_exit_2(capsys):
    assert main([*ARGS, "--scheduler", "tcp://127.0.0.1:1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("canfdi evaluate: --scheduler tcp://127.0.0.1:1: no scheduler")
    assert len(err.splitlines()) == 1


def test_jobs_below_one_exit_2(capsys):
    assert main([*ARGS, "--jobs", "0"]) == 2
    assert "--jobs: at least 1" in capsys.readouterr().err
