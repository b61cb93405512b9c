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
    return {(r["set"], r["run"], m, u): v["position_mm"]
            for r in records for m, rec in r["methods"].items() for u, v in rec["units"].items()}


def test_cli_quick_writes_json(tmp_path, capsys):
    out = tmp_path / "t1.json"
    assert main(["benchmark", "table1", "--quick", "--methods", "om,mmm", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["config"]["methods"] == ["om", "mmm"] and len(doc["records"]) == 1
    om, mmm = (doc["summary"]["methods"][m]["average"]["position_mm"][0] for m in ("om", "mmm"))
    assert om < 5.0 and om < mmm  # noise-free: OM within 5 mm, and better than the baseline
    printed = capsys.readouterr().out
    assert "Table I" in printed and "om" in printed


def test_summary_matches_numpy(quick, serial):
    s = summarise(quick, serial)["methods"]["om"]
    values = [r["methods"]["om"]["units"]["su2"]["position_mm"] for r in serial]
    assert s["units"]["su2"]["position_mm"] == pytest.approx([np.mean(values), np.std(values)])
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


def test_the_table_prints_positions_in_mm_beside_the_papers_converted_from_cm():
    """Positions in mm like every other table; the paper's rows (printed in cm there) converted."""
    from rich.console import Console

    from skincal.bench.table1 import PAPER_TABLE_I, table1_table

    assert PAPER_TABLE_I["om"]["position_mm"][0] == pytest.approx((2.8, 1.5))  # the paper's SU1: 0.28 +- 0.15 cm
    assert PAPER_TABLE_I["mmm"]["position_mm"][-1] == pytest.approx((44.0, 59.0))
    config = Table1Config(methods=("om",))
    stat = {"position_mm": [3.0, 1.0], "quaternion_distance": [0.001, 0.0005], "rotation_deg": [0.1, 0.05]}
    units = {f"su{k + 1}": {"link": link, **stat} for k, link in enumerate(config.links)}
    summary = {"methods": {"om": {"units": units, "average": stat, "runtime_s": [1.0, 0.1], "failed": 0}}}
    console = Console(width=400, record=True)
    console.print(table1_table(config, summary))
    text = console.export_text()
    assert "position (mm)" in text and "(cm)" not in text
    assert "3.0 ± 1.0" in text and "2.8 ± 1.5" in text and "6.6 ± 6.0" in text  # ours, the paper's SU1, average
