"""``skincal benchmark table1`` in its quick form: the command, the statistics, local processes and Dask."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skincal.bench.table1 import Table1Config, jobs, run_dask, run_job, run_local, summarise
from skincal.cli import main


@pytest.fixture(scope="module")
def quick():
    return Table1Config.quick(methods=("om", "mmm"), runs=2)


@pytest.fixture(scope="module")
def serial(quick):
    return [run_job(job) for job in jobs(quick)]


def _positions(records):
    return {(r["set"], r["run"], m, u): v["position_cm"]
            for r in records for m, rec in r["methods"].items() for u, v in rec["units"].items()}


def test_cli_quick_writes_json(tmp_path, capsys):
    out = tmp_path / "t1.json"
    assert main(["benchmark", "table1", "--quick", "--methods", "om,mmm", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["config"]["methods"] == ["om", "mmm"] and len(doc["records"]) == 1
    om, mmm = (doc["summary"]["methods"][m]["average"]["position_cm"][0] for m in ("om", "mmm"))
    assert om < 0.5 and om < mmm  # noise-free: OM within 5 mm, and better than the baseline
    printed = capsys.readouterr().out
    assert "Table I" in printed and "om" in printed


def test_summary_matches_numpy(quick, serial):
    s = summarise(quick, serial)["methods"]["om"]
    values = [r["methods"]["om"]["units"]["su2"]["position_cm"] for r in serial]
    assert s["units"]["su2"]["position_cm"] == pytest.approx([np.mean(values), np.std(values)])
    assert s["units"]["su2"]["link"] == 7
    every = [u["quaternion_distance"] for r in serial for u in r["methods"]["om"]["units"].values()]
    assert s["average"]["quaternion_distance"] == pytest.approx([np.mean(every), np.std(every)])
    assert s["runtime_s"][0] > 0


def test_local_processes_repeat_serial_results(quick, serial):
    seen = []
    records = run_local(quick, workers=2, progress=seen.append)
    assert len(seen) == len(records) == 2
    assert _positions(records) == pytest.approx(_positions(serial))


def test_dask_local_cluster_on_loopback(quick, serial):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None
    ) as cluster:
        records = run_dask(quick, cluster.scheduler_address)
    assert len(records) == 2
    assert _positions(records) == pytest.approx(_positions(serial))


def test_bad_method_is_one_line_error(capsys):
    assert main(["benchmark", "table1", "--quick", "--methods", "om,nope"]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown method(s) nope" in err and "\n" not in err
