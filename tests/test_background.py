"""tests/background.py: a job runs at the lowest priority, its result is collected once and
kept, and a job that fails or was never started gives None (the test then does the work)."""

import re
import shutil
from pathlib import Path

import pytest

import background


def _script(tmp_path, name, body):
    path = tmp_path / f"{name}.py"
    path.write_text("import json, os, sys\n" + body)
    return path


def test_a_job_runs_niced_and_its_result_is_kept(tmp_path):
    script = _script(tmp_path, "ok", "json.dump({'nice': os.nice(0), 'argv': sys.argv[1:]}, "
                     "open(sys.argv[1], 'w'))\n")
    background.start("test_ok", script)
    got = background.result("test_ok", timeout=60)
    assert got["nice"] == 19 and got["argv"][0].endswith("result.json")
    assert background.result("test_ok") is got


def test_a_failed_job_gives_none_with_a_warning(tmp_path):
    background.start("test_fails", _script(tmp_path, "fails", "sys.exit(3)\n"))
    with pytest.warns(UserWarning, match="test_fails failed") as caught:
        assert background.result("test_fails", timeout=60) is None
    log = Path(re.search(r"its log: (\S+)\)", str(caught[0].message)).group(1))
    assert log.exists()   # kept for the reader of the warning
    shutil.rmtree(log.parent)


def test_a_job_never_started_gives_none():
    assert background.result("test_never_started") is None


def test_a_job_over_its_time_is_stopped(tmp_path):
    background.start("test_slow", _script(tmp_path, "slow", "import time; time.sleep(60)\n"))
    assert background.result("test_slow", timeout=0.5) is None
