"""The data channel with real server and node processes over loopback: a data socket cut
while the websocket stays up is reopened and the part completes intact; a node that
cannot open the channel (firewall) falls back to the websocket and completes intact.

(The corrupt chunk, server kill and node kill of ``tests/app/data/test_transfer_faults``
run over the data channel too: it is the default path.)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.app.data.test_record_flow import record, setup_session, wait_state
from tests.app.data.test_transfer_faults import assert_identical
from tests.integration.conftest import Rig
from tests.integration.conftest import make_rig as make_rig  # the fixture, for pytest

SMALL_CHUNKS = {"GAITRIG_TEST_CHUNK_SIZE": "1024", "GAITRIG_TEST_CHUNK_DELAY_S": "0.01",
                "GAITRIG_TRANSFER_PORT": "0"}


def _record_until_complete(rig: Rig, tmp_path: Path) -> None:
    """One node records 2 s; its part must reach the server byte-identical."""
    rig.start_node("S1")
    rig.wait_online(["S1"])
    ids = setup_session(rig)
    rec_id = record(rig, ids["session"]["id"], seconds=2.0)
    r = wait_state(rig, rec_id, {"complete"}, timeout=90)
    assert r["parts"][0]["state"] == "complete"
    assert_identical(rig, tmp_path / "server", rec_id, "S1")


@pytest.mark.timeout(240)
def test_data_socket_cut_is_reopened(make_rig: Any, tmp_path: Path) -> None:
    rig: Rig = make_rig({**SMALL_CHUNKS, "GAITRIG_TEST_CUT_DATA_CHANNEL": "frames.bin:3"})
    _record_until_complete(rig, tmp_path)
    assert "cutting the data channel before frames.bin chunk 3" in rig.log_text("S1")
    server = rig.log_text("server")
    assert "data channel from S1 broke" in server and "reopening it" in server
    assert "no data channel" not in server  # the websocket was not needed


@pytest.mark.timeout(240)
def test_blocked_data_channel_falls_back_to_the_websocket(make_rig: Any, tmp_path: Path
                                                          ) -> None:
    rig: Rig = make_rig({**SMALL_CHUNKS, "GAITRIG_TEST_BLOCK_DATA_CHANNEL": "1",
                         "GAITRIG_TEST_CORRUPT_CHUNK": "frames.bin:2"})
    _record_until_complete(rig, tmp_path)
    assert "no data channel from S1" in rig.log_text("server")
    # the websocket path still rejects a damaged chunk and fetches it again
    assert "flipping one byte of frames.bin chunk 2" in rig.log_text("S1")
