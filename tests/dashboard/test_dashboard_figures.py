import numpy as np
import pandas as pd
import pytest

from dashboard import figures


def scene():
    t = np.arange(0, 1.0, 0.5)
    ego = pd.DataFrame(
        {
            "t_s": t,
            "ego_x_m": 20.0 * t,
            "ego_v_mps": 20.0,
            "ego_lane": [0, 0],
            "ego_length_m": 4.5,
            "lc_button": [False, True],
            "lc_direction": [None, "left"],
        }
    )
    traffic = pd.DataFrame(
        {
            "t_s": [0.0, 0.0, 0.0, 0.5],
            "vehicle_id": ["a", "b", "c", "a"],
            "x_m": [30.0, -20.0, 10.0, 35.0],
            "lane": [0, 0, 1, 0],
            "length_m": [4.5, 5.5, 4.5, 4.5],
        }
    )
    return ego, traffic


def test_lane_gaps_bumper_to_bumper():
    ego, traffic = scene()
    g = figures.lane_gaps(ego, traffic)
    assert g["t_s"].tolist() == [0.0, 0.5]
    # t=0: leader at 30 m -> 30 - 4.5 = 25.5; follower at -20 m, length 5.5 -> 20 - 5 = 15
    assert g["lead_gap_m"].tolist() == pytest.approx([25.5, 35.0 - 10.0 - 4.5])
    assert g["follow_gap_m"].iloc[0] == pytest.approx(15.0) and np.isnan(g["follow_gap_m"].iloc[1])


def test_timeline_marks_presses_and_has_units():
    ego, traffic = scene()
    assert figures.press_times(ego)[["t_s", "direction"]].values.tolist() == [[0.5, "left"]]
    fig = figures.recording_timeline(ego, traffic)
    titles = [fig.layout[a].title.text for a in ("yaxis", "yaxis2", "yaxis3", "xaxis3")]
    assert titles == ["ego speed [m/s]", "lane [index, 0 = right]", "gap in ego lane [m]", "time [s]"]
    press = [tr for tr in fig.data if tr.name == "button press"][0]
    assert list(press.x) == [0.5]


def test_runs_curves_smoothed_per_run():
    m = pd.DataFrame({"episode": range(1, 21), "loss": [0.0, 2.0] * 10})
    fig = figures.runs_curves({"a": m, "b": m.head(4)}, "loss", "loss [-]", smoothing=0.5)
    assert [t.name for t in fig.data] == ["a", "b"]
    assert list(fig.data[0].y[:2]) == pytest.approx([0.0, 1.0 / 0.75])  # debiased: no pull towards 0
    assert list(figures.runs_curves({"b": m.head(4)}, "loss", "-", smoothing=0.0).data[0].y) == [0.0, 2.0, 0.0, 2.0]
    assert fig.layout.xaxis.title.text == "episode [-]" and fig.layout.yaxis.title.text == "loss [-]"
