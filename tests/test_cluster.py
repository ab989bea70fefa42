"""Campaigns and searches on a Dask cluster on loopback: a scheduler and two workers as processes,
each worker in a folder of its own (they share no file system with the campaign but what the
scheduler carries). One worker is killed mid-campaign; the rows are those of a local campaign."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time

import pytest
from conftest import ONE_AT_A_TIME, ROOT, WELDING_CELL
from live_processes import free_port, processes, wait_listening

pytestmark = [pytest.mark.slow, ONE_AT_A_TIME]  # five processes on loopback: skip locally with -m "not slow"
TWO_OPERATORS = ROOT / "scenarios" / "two_operators.yaml"
ROW = ("index", "seed", "configuration", "status", "verdict", "verdicts", "violations", "undecided", "use_cases", "coverage")


def _cellsim(*args, timeout=600, env=None):
    return subprocess.run([sys.executable, "-m", "cellsim", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT, env={**os.environ, "COLUMNS": "200", **(env or {})})


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """``dask scheduler`` and two ``dask worker`` processes (no nanny: a killed worker stays dead)."""
    from distributed import Client

    base = tmp_path_factory.mktemp("cluster")
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    with processes() as start:
        (base / "scheduler").mkdir()
        scheduler = start(["--host", "127.0.0.1", "--port", str(port), "--no-dashboard"], base / "scheduler.log",
                          module="distributed.cli.dask_scheduler", cwd=base / "scheduler")
        # (a client that connects before the scheduler has finished starting can be dropped: wait for its banner)
        wait_listening(scheduler, port, 120, "the Dask scheduler", ready="Scheduler at:")
        workers = []
        for name in ("w1", "w2"):
            folder = base / name
            folder.mkdir()
            workers.append(start([address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny", "--no-dashboard",
                                  "--local-directory", str(folder)], base / f"{name}.log",
                                 module="distributed.cli.dask_worker", cwd=folder))
        with Client(address, timeout=120) as client:
            client.wait_for_workers(2, timeout=120)
        yield address, workers, base


def _rows(results: dict) -> list[dict]:
    return [{k: r.get(k) for k in ROW} for r in results["runs"]]


def test_two_campaigns_on_one_scheduler_each_run_their_own_inputs(cluster, tmp_path):
    """An audit found the inputs scattered under their files' names: a second campaign whose welding_cell.yaml differs
    ran the first's on the cluster (its operator's waits summed to 20 s where its own file says 8). Each campaign's
    runs on the cluster are now its own local runs."""
    import shutil

    address, _, _ = cluster
    folders = {}
    for name, total in (("first", "20.0"), ("second", "8.0")):
        folder = tmp_path / name
        shutil.copytree(WELDING_CELL.parent, folder, ignore=shutil.ignore_patterns("*.md"))
        text = (folder / WELDING_CELL.name).read_text()
        assert "operator_waits: {kind: simplex, total: 20.0}" in text
        (folder / WELDING_CELL.name).write_text(text.replace("operator_waits: {kind: simplex, total: 20.0}",
                                                             f"operator_waits: {{kind: simplex, total: {total}}}"))
        folders[name] = folder / WELDING_CELL.name
    # the first campaign still holds its inputs on the cluster while the second runs
    first = subprocess.Popen([sys.executable, "-m", "cellsim", "campaign", str(folders["first"]), "--runs", "6",
                              "--seed", "5", "--scheduler", address, "--out", str(tmp_path / "first-cluster"),
                              "--quiet"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while not list((tmp_path / "first-cluster" / "runs").glob("*/result.json")):  # under way on the cluster
            assert first.poll() is None, first.communicate()
            assert time.monotonic() < deadline, "no run of the first campaign came back"
            threading.Event().wait(0.05)
        done = _cellsim("campaign", folders["second"], "--runs", "2", "--seed", "5", "--scheduler", address,
                        "--out", tmp_path / "second-cluster", "--quiet")
        assert done.returncode in (0, 1), done.stderr
        _, stderr = first.communicate(timeout=600)
        assert first.returncode in (0, 1), stderr
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    local = _cellsim("campaign", folders["second"], "--runs", "2", "--seed", "5", "--jobs", "1",
                     "--out", tmp_path / "second-local", "--quiet")
    assert local.returncode in (0, 1), local.stderr
    remote = json.loads((tmp_path / "second-cluster" / "results.json").read_text())
    assert _rows(remote) == _rows(json.loads((tmp_path / "second-local" / "results.json").read_text()))
    waits = [sum(v for k, v in r["configuration"].items() if k.endswith(".wait")) for r in remote["runs"]]
    assert waits == [pytest.approx(8.0)] * 2


def test_a_search_on_the_cluster_is_the_search_run_locally(cluster, tmp_path):
    address, _, _ = cluster
    args = ["falsify", TWO_OPERATORS, "--budget", "20", "--seed", "3", "--quiet"]
    remote = _cellsim(*args, "--scheduler", address, "--out", tmp_path / "remote")
    local = _cellsim(*args, "--jobs", "1", "--out", tmp_path / "local")
    assert remote.returncode == local.returncode == 1, remote.stderr
    a = json.loads((tmp_path / "remote" / "results.json").read_text())
    b = json.loads((tmp_path / "local" / "results.json").read_text())
    assert a["search"]["first_violation"] == b["search"]["first_violation"]
    first = a["search"]["first_violation"]
    pick = lambda results: [(r["index"], r["search"], r["violations"]) for r in results["runs"] if r["index"] <= first]  # noqa: E731
    assert pick(a) == pick(b)


def test_a_campaign_on_the_cluster_survives_a_killed_worker_and_gives_the_local_rows(cluster, tmp_path):
    """(Last of the tests on the module's cluster: it leaves it one worker.)"""
    address, workers, base = cluster
    out, local = tmp_path / "on-cluster", tmp_path / "local"
    runs = 6  # after three are back, one is in flight on each worker and one waits: the killed one's is retried
    campaign = subprocess.Popen([sys.executable, "-m", "cellsim", "campaign", str(TWO_OPERATORS), "--runs", str(runs),
                                 "--seed", "4", "--scheduler", address, "--out", str(out), "--quiet"],
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while len(list((out / "runs").glob("*/result.json"))) < 3:  # a few runs back: the cluster is busy
            assert campaign.poll() is None, campaign.communicate()
            assert time.monotonic() < deadline, "no run came back from the cluster"
            threading.Event().wait(0.05)
        os.kill(workers[1].pid, signal.SIGKILL)
        workers[1].popen.wait(timeout=30)
        _, stderr = campaign.communicate(timeout=600)
    finally:
        if campaign.poll() is None:
            campaign.kill()
            campaign.wait()
    assert campaign.returncode in (0, 1), stderr
    assert "Traceback" not in stderr
    done = _cellsim("campaign", TWO_OPERATORS, "--runs", runs, "--seed", "4", "--jobs", "2", "--out", local, "--quiet")
    assert done.returncode == campaign.returncode, done.stderr
    remote_results = json.loads((out / "results.json").read_text())
    local_results = json.loads((local / "results.json").read_text())
    assert _rows(remote_results) == _rows(local_results)  # same seed, same runs, same verdicts
    assert [r["index"] for r in remote_results["runs"]] == list(range(runs))  # each once
    assert sorted(p.name for p in (out / "runs").iterdir()) == [f"{i:04d}" for i in range(runs)]
    assert remote_results["totals"] == local_results["totals"]
    record = remote_results["cluster"]
    assert record["scheduler"] == address and record["workers"] == 1
    assert record["retries"] >= 1  # the killed worker's runs were handed to the other
    report = (out / "report.html").read_text()
    assert f"Retried runs</th><td class=\"num\">{record['retries']}" in report
    # every run folder is whole and re-checks as the campaign recorded it
    for r in remote_results["runs"][:3]:
        checked = _cellsim("check", out / r["out"], "--json")
        assert json.loads(checked.stdout)["verdict"] == r["verdict"]
    # resuming the same campaign locally keeps every run: same content identity
    again = _cellsim("campaign", TWO_OPERATORS, "--runs", runs, "--seed", "4", "--jobs", "1", "--out", out)
    assert f"{runs} ({runs} resumed" in again.stdout


@pytest.mark.parametrize("command", [("campaign", "--runs", "2"), ("falsify", "--budget", "2")])
def test_an_unreachable_scheduler_is_one_line_and_exit_2_with_nothing_written(tmp_path, command):
    done = _cellsim(*command[:1], WELDING_CELL, *command[1:], "--scheduler", f"tcp://127.0.0.1:{free_port()}",
                    "--out", tmp_path / "c", timeout=120)
    assert done.returncode == 2
    assert "cannot reach the Dask scheduler" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "c").exists()  # refused before the folder was touched: the same command works later


@pytest.mark.parametrize("command", [("campaign", "--runs", "2"), ("falsify", "--budget", "2")])
@pytest.mark.parametrize("answer", [None, b"HTTP/1.1 200 OK\r\nContent-Length: 0\r\n\r\n"])
def test_a_port_that_is_no_dask_scheduler_is_one_line_within_its_limit_and_exit_2_with_nothing_written(
        tmp_path, command, answer):
    """A listener that accepts and stays silent (or answers HTTP) used to hold the campaign for ever, after it had
    written campaign.json and inputs/. It is asked, in Dask's protocol, who it is; no scheduler answers within the
    limit (CELLSIM_SCHEDULER_TIMEOUT, 2 s here: 10 s by default)."""
    import socket
    import threading
    import time

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    port = server.getsockname()[1]
    stop, accepted = threading.Event(), []

    def serve() -> None:  # accepts, and answers nothing (or HTTP), keeping the connections open
        server.settimeout(0.1)
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            accepted.append(conn)
            if answer is not None:
                conn.sendall(answer)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        began = time.monotonic()
        done = _cellsim(*command[:1], WELDING_CELL, *command[1:], "--scheduler", f"tcp://127.0.0.1:{port}",
                        "--out", tmp_path / "c", timeout=120, env={"CELLSIM_SCHEDULER_TIMEOUT": "2"})
        took = time.monotonic() - began
    finally:
        stop.set()
        thread.join(5)
        for conn in accepted:
            conn.close()
        server.close()
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert f"127.0.0.1:{port}" in done.stderr and "Dask scheduler" in done.stderr
    assert accepted and took < 2 + 15  # the 2 s limit, and a process's start
    if answer is None:
        assert "within 2 s" in done.stderr
    assert not (tmp_path / "c").exists()


def test_a_scheduler_timeout_that_is_no_positive_number_is_one_line_and_exit_2(tmp_path):
    done = _cellsim("campaign", WELDING_CELL, "--runs", "2", "--scheduler", "tcp://127.0.0.1:1", "--out", tmp_path / "c",
                    env={"CELLSIM_SCHEDULER_TIMEOUT": "soon"})
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "CELLSIM_SCHEDULER_TIMEOUT=soon: expected seconds above 0" in done.stderr
    assert not (tmp_path / "c").exists()


def test_a_malformed_scheduler_address_is_a_usage_error(tmp_path):
    done = _cellsim("campaign", WELDING_CELL, "--scheduler", "127.0.0.1:8786", "--out", tmp_path / "c")
    assert done.returncode == 2 and "tcp://HOST:PORT" in done.stderr
