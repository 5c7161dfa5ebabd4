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


def test_by_index_puts_each_step_by_its_place_in_the_walk():
    """``_by_index``: the first kept step (R1 − L1) is ``first``, the next ``second``, the
    rest by side; an unmatched reference step leaves its place empty (errors in cm)."""
    from bench.gait_error_budget import _by_index
    from engine.gait import Step

    ref = [Step(s, t, 0.70, 0.10, 0.55) for s, t in zip("RLRL", (2.4, 3.0, 3.6, 4.2),
                                                         strict=True)]
    meas = [Step("R", 2.41, 0.72, 0.11, 0.55), Step("R", 3.61, 0.69, 0.10, 0.55),
            Step("L", 4.19, 0.70, 0.13, 0.55)]  # the first left step missed
    out: dict[str, list[float]] = {}
    _by_index(meas, ref, out, "one")
    assert out["one step_length first"] == [pytest.approx(2.0)]
    assert out["one step_width first"] == [pytest.approx(1.0)]
    assert "one step_length second" not in out
    assert out["one step_length later R"] == [pytest.approx(-1.0)]
    assert out["one step_width later L"] == [pytest.approx(3.0)]


def test_a_variant_can_let_the_paper_mean_keep_inferred_joints():
    """``"paper_keeps_inferred": true`` in a variant is not a model field: it makes the
    paper's mean keep INFERRED joints (the same walks and draws), so the one-sided
    placements, where the far ankle is often inferred, change and the default's do not."""
    from bench.gait_error_budget import run

    out = run(1, 1, 0, [{}, {"paper_keeps_inferred": True}, {}])
    assert out["v1"]["model"] == {"paper_keeps_inferred": True}
    assert out["v0"]["one step_length L"] == out["v2"]["one step_length L"]
    rows = [k for k in out["v0"] if k.startswith("one step")]
    assert any(out["v1"][k] != out["v0"][k] for k in rows)
