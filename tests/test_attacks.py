"""Attacks on the live twin replayed through real processes on loopback (issue "A secure online twin").

The test plays a light curtain on its physical key (as the cell's devices would, through the
bridge or an emulator), and between its samples what someone with a foothold on the cell network
sent: a sample stamped a million seconds ahead, a 400 kB nested payload, and time stamps and
sequence numbers of 400 digits. The twin must keep believing the real curtain, fail safe on what
it cannot read, recover, and never stop.
"""

from __future__ import annotations

import json
import threading
import time

import pytest
from conftest import ONE_AT_A_TIME

from cellsim.live.codec import encode_fields
from cellsim.services.blackbox import BlackBox

from live_processes import ROOT, ChannelWatch, free_port, observer, processes, wait_alive

pytestmark = [pytest.mark.slow, ONE_AT_A_TIME]  # processes on loopback: skip locally with -m "not slow"

WELDING_CELL = str(ROOT / "scenarios" / "welding_cell.yaml")
CURTAIN = "cellsim/welding_cell/physical/light_barrier"


class Curtain:
    """The real curtain: its samples at 25 Hz on a thread, broken as ``broken`` says, counting its sequence."""

    def __init__(self, publisher):
        self.publisher, self.broken, self.seq = publisher, True, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._lock = threading.Lock()
        self._thread.start()

    def next_seq(self) -> int:
        with self._lock:
            self.seq += 1
            return self.seq

    def _run(self) -> None:
        while not self._stop.is_set():
            self.publisher.put(encode_fields(time.time(), self.next_seq(), {"broken": self.broken}))
            self._stop.wait(0.04)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


def test_forged_future_stamps_and_oversized_payloads_neither_fool_nor_stop_the_twin(tmp_path):
    port = free_port()
    with processes() as start:
        twin = start(["live", WELDING_CELL, "--out", str(tmp_path / "twin"), "--listen", f"tls/127.0.0.1:{port}",
                      "--quiet", "--set", "light_barrier.twin.mode=shadow", "--wait-physical", "0"], tmp_path / "twin.log")
        # the attacker holds the bridge's certificate: a foothold on a legitimate sender of samples
        with observer(port) as session, observer(port, role="bridge") as attacker:
            wait_alive(session, "cellsim/welding_cell/alive/twin")
            broken = ChannelWatch(session, "cellsim/welding_cell/twin/light_barrier/broken")
            link = ChannelWatch(session, "cellsim/welding_cell/twin/light_barrier/physical_link")
            publisher = attacker.declare_publisher(CURTAIN)
            curtain = Curtain(publisher)
            try:
                link.wait_for("ok", 30)
                broken.wait_for(True, 5)  # the real curtain: broken (someone is in the beams)

                # 1. a sample stamped a million seconds ahead saying "clear": refused, and it does not
                #    make the later real samples look old
                publisher.put(encode_fields(time.time() + 1e6, curtain.next_seq(), {"broken": False}))
                seen = len(broken.values)
                threading.Event().wait(1.0)  # a second of real samples after it (25 of them)
                assert broken.values[seen:] == [] and broken.values[-1] is True, broken.values
                assert link.values[-1] == "ok", link.values

                # 2. what cannot be read: the twin reads its link corrupt (fails safe), then trusts the real
                #    samples again; it does not stop
                for payload in (b"[" * 200_000 + b"]" * 200_000,
                                json.dumps({"t": 10 ** 400, "seq": curtain.next_seq(), "fields": {"broken": False}}).encode(),
                                json.dumps({"t": time.time(), "seq": 10 ** 400, "fields": {"broken": False}}).encode()):
                    publisher.put(payload)
                    link.wait_for("corrupt", 5)
                    link.wait_for("ok", 5)
                assert broken.values[-1] is True and False not in broken.values[seen:]
                assert twin.popen.poll() is None, twin.output()  # still running
            finally:
                curtain.stop()
                broken.close()
                link.close()
        twin.stop()
        assert twin.popen.returncode == 130, twin.output()
    with BlackBox(tmp_path / "twin" / "blackbox.sqlite") as bb:
        metadata = bb.metadata()
        assert metadata["status"] == "stopped"
        assert metadata["live"]["rejected_samples"]["light_barrier"] >= 4  # each forged or unreadable one counted
        # the real curtain said broken throughout, and so did the twin: never clear, whatever was forged
        assert bb.series("light_barrier.broken").values == [True]
    assert "refused a message" in (tmp_path / "twin.log").read_text()  # and said so, with its key
