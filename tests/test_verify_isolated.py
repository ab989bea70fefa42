"""Work in processes of their own (cellsim.verify.isolated): results and errors come back, stages are relayed,
a child that dies is reported, and no child outlives the call."""

from __future__ import annotations

import os

import pytest

from cellsim.verify.isolated import ProcessStopped, in_own_process, side_by_side


def test_a_childs_stages_result_and_error_come_back_to_the_caller():
    stages = []

    def work(say):
        say("one")
        say("two")
        return {"pid": os.getpid(), "value": [1, 2.5, "x"]}

    result = in_own_process(work, stages.append)
    assert stages == ["one", "two"] and result["value"] == [1, 2.5, "x"]
    assert result["pid"] != os.getpid()  # it did run elsewhere

    def fails(say):
        raise ValueError("the model is wrong")

    with pytest.raises(ValueError, match="the model is wrong"):
        in_own_process(fails)


def test_a_child_that_ends_without_a_result_is_reported_with_how_it_ended():
    with pytest.raises(ProcessStopped, match="exit status 1"):
        in_own_process(lambda say: os._exit(1))  # as Sylvan does when its tables are full
    with pytest.raises(ProcessStopped, match="signal SIGKILL"):
        in_own_process(lambda say: os.kill(os.getpid(), 9))


def test_side_by_side_gives_results_in_order_and_runs_them_at_once():
    read, write = os.pipe()

    def waits_for_the_other(say):  # ends only once the second has run: they must run at the same time
        import signal
        signal.alarm(20)  # run one after the other, it would wait for ever: it dies instead, and the test fails
        os.close(write)
        return os.read(read, 1) == b"!" and "first"

    def lets_the_first_go(say):
        os.write(write, b"!")
        return "second"

    assert side_by_side([waits_for_the_other, lets_the_first_go], at_once=2) == ["first", "second"]
    assert side_by_side([lambda say, i=i: i * i for i in range(5)], at_once=2) == [0, 1, 4, 9, 16]
    os.close(read)
    os.close(write)


def test_an_error_in_one_of_a_batch_is_raised_and_leaves_no_child_running(tmp_path):
    """The batch's error is raised as soon as the failing child has ended: the child still at work is stopped, not
    waited out (it would have left its mark after a minute), and work not yet started is never started."""
    finished, started = tmp_path / "finished", tmp_path / "started"

    def fails(say):
        raise RuntimeError("this replay failed")

    def sleeps(say):
        import time
        time.sleep(60)  # noqa - stands for a long simulation: it must be stopped, not waited for
        finished.write_text("waited out")

    def later(say):
        started.write_text("started")

    before = _children()
    with pytest.raises(RuntimeError, match="this replay failed"):
        side_by_side([fails, sleeps, later], at_once=2)
    assert _children() == before
    assert not finished.exists() and not started.exists()


def _children() -> set[str]:
    with open(f"/proc/{os.getpid()}/task/{os.getpid()}/children") as f:
        return set(f.read().split())


def test_the_floor_measured_in_parts_side_by_side_is_the_floor_measured_in_one_process(monkeypatch):
    """The welding cell's poses measured in two forked processes and in this one alone give the same places, so the
    same model, byte for byte."""
    import cellsim.verify.floor as floor
    import cellsim.verify.isolated as isolated
    from cellsim.scenario import load_scenario
    from cellsim.verify.run import abstract_model

    from conftest import WELDING_CELL

    sf = load_scenario(WELDING_CELL)
    monkeypatch.setattr(floor, "SIDE_BY_SIDE_FROM", 10**9)
    alone = abstract_model(sf)
    monkeypatch.setattr(floor, "SIDE_BY_SIDE_FROM", 1)
    monkeypatch.setattr(isolated, "cores", lambda: 2)
    forks = []
    start = isolated._start
    monkeypatch.setattr(isolated, "_start", lambda work: forks.append(1) or start(work))
    parts = abstract_model(sf)
    assert len(forks) == 2  # the one person's poses, in two parts
    assert parts.cell.places.poses_measured == alone.cell.places.poses_measured > 1000
    assert parts.cell.program(parts.header).text() == alone.cell.program(alone.header).text()
