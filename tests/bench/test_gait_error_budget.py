"""The error-budget bench's transcription of seed 000's Tables 2–3."""

import pytest

from bench.gait_error_budget import PAPER_ROWS, targets


@pytest.mark.parametrize("side", ["one", "two"])
def test_rpc_is_1_96_sd_of_the_differences_in_every_row(side):
    """Each row's RPC equals 1.96·SD(Kinect − Vicon) from its own SDs and r (Tables 2–3
    captions: "RPC: reproducibility coefficient (1.96*SD)"), so the transcribed numbers
    are consistent and the error-variance targets (RPC/1.96)² mean what they say."""
    for row, (sd_k, sd_v, r, _bias, rpc) in PAPER_ROWS[side].items():
        var = sd_k**2 + sd_v**2 - 2 * r * sd_k * sd_v
        # the table rounds SDs to 0.01 cm and r to 0.001
        assert var == pytest.approx((rpc / 1.96) ** 2, rel=0.03), row
        assert targets()[side][row]["err_var"] == pytest.approx((rpc / 1.96) ** 2, abs=0.05)
