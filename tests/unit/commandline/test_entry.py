"""The ``fogfleet`` command sizes NumPy's BLAS thread pool before NumPy loads it."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from fogfleet.commandline.entry import THREAD_POOL_VARIABLES

# after a product large enough for OpenBLAS to use its pool: the process's thread count
COUNT_THREADS = (
    "import numpy as np, os; a = np.ones((600, 600)); a @ a; "
    "print(len(os.listdir('/proc/self/task')))"
)


def _threads(prelude: str, env: dict[str, str]) -> int:
    out = subprocess.run(
        [sys.executable, "-c", prelude + COUNT_THREADS],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return int(out.stdout.strip())


def _clean_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in THREAD_POOL_VARIABLES}


def test_the_command_runs_numpy_with_one_blas_thread() -> None:
    env = _clean_env()
    pinned = _threads(
        "from fogfleet.commandline.entry import pin_thread_pools; pin_thread_pools(); ", env
    )
    assert pinned == 1
    if (os.cpu_count() or 1) > 1:  # the control: unpinned, OpenBLAS starts one per core
        assert _threads("", env) > 1


def test_a_value_the_user_set_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    from fogfleet.commandline.entry import pin_thread_pools

    for name in THREAD_POOL_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "4")
    pin_thread_pools()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "4"
    assert os.environ["OMP_NUM_THREADS"] == "1"


@pytest.mark.integration
def test_python_m_fogfleet_goes_through_the_entry_point() -> None:
    env = _clean_env()
    code = (
        "import runpy, sys, os; sys.argv = ['fogfleet', '--help']\n"
        "try:\n    runpy.run_module('fogfleet', run_name='__main__')\n"
        "except SystemExit:\n    pass\n"
        "print(os.environ.get('OPENBLAS_NUM_THREADS'))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip().splitlines()[-1] == "1"
