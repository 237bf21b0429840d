from pathlib import Path

import pandas as pd

from dashboard import views
from dashboard.uploads import SavedUpload


def test_upload_rows_joins_report_by_path():
    saved = [
        SavedUpload("a.csv", 3, Path("/w/uploads/h1/a.csv")),
        SavedUpload("e.csv", 0, None, "empty file"),
        SavedUpload("b.mcap", 5, Path("/w/uploads/h2/b.mcap")),
    ]
    report = {
        "files": [
            {
                "path": "/w/uploads/h1/a.csv",
                "status": "ingested",
                "reason": "",
                "recording_id": "r1",
                "driver_id": "D1",
            },
            {"path": "/w/uploads/h2/b.mcap", "status": "rejected", "reason": "no /ego/state topic"},
        ]
    }
    rows = views.upload_rows(saved, report)
    assert rows["status"].tolist() == ["ingested", "refused", "rejected"]
    assert rows["reason"].tolist() == ["", "empty file", "no /ego/state topic"]
    assert rows["recording_id"].tolist() == ["r1", "", ""]


def test_undefined_decisions_lists_only_presses_with_a_reason():
    dec = pd.DataFrame(
        {
            "driver_id": ["D1", "D1", "D1", "D2"],
            "label": ["change", "change", "keep", "change"],
            "session_id": "s",
            "t_s": [1.0, 2.0, 0.5, 3.0],
            "ego_v_mps": 20.0,
            "t_f_status": ["ok", "not_closing", "absent", "absent"],
            "t_nf_status": ["ok", "ok", "ok", "ok"],
            "dv_nb_status": ["ok", "ok", "ok", "ok"],
        }
    )
    bad = views.undefined_decisions(dec, "D1")
    assert bad["t_s"].tolist() == [2.0] and bad["t_f_status"].tolist() == ["not_closing"]


def test_style_summary_and_for_driver():
    styles = pd.DataFrame(
        {
            "driver_id": ["D1", "D2", "D3"],
            "style": ["Normal", "Normal", "Aggressive"],
            "is_typical": [False, True, True],
        }
    )
    meta = {"summary": {"style_descriptions": {"Normal": "follows at 1.5 s"}}}
    s = views.style_summary(styles, meta)
    assert s.to_dict("records") == [
        {
            "style": "Normal",
            "drivers": 2,
            "typical driver": "D2",
            "members": "D1, D2",
            "what sets it apart": "follows at 1.5 s",
        },
        {"style": "Aggressive", "drivers": 1, "typical driver": "D3", "members": "D3", "what sets it apart": ""},
    ]
    styles["confidence"] = [0.97, 0.5, 0.8]
    styles["unsure"] = ["", "only 3 presses", "*readings* disagree"]
    unsure = views.unsure_drivers(styles)
    assert unsure["driver"].tolist() == ["D2", "D3"] and unsure["why unsure"].tolist()[1] == "*readings* disagree"
    skipped = pd.DataFrame(
        {"what": ["driver", "indicator", "indicator"], "id": ["D1", "D1:t_nf", "D10:t_f"], "reason": ["a", "b", "c"]}
    )
    assert views.for_driver(skipped, "D1")["reason"].tolist() == ["a", "b"]


def test_evaluation_table_in_percent_and_compare():
    summary = [
        {"who": "agent", "recall": 0.959, "timing_mae_s": 0.25, "medae_t_f": None},
        {"who": "greedy", "recall": 0.837, "timing_mae_s": 1.5, "medae_t_f": 0.7},
    ]
    t = views.evaluation_table(summary)
    assert t["policy"].tolist() == ["agent", "greedy"]
    assert t["recall at the presses [%]"].tolist() == [95.9, 83.7]
    assert t["timing MAE [s]"].tolist() == [0.25, 1.5]
    assert t["median |err| t_f [s]"].isna().tolist() == [True, False]
    assert "median" in views.EVAL_DEFINITION and "minutes" in views.EVAL_DEFINITION
    both = views.compare_runs({"r1": t, "r2": t.head(1)})
    assert both["run_id"].tolist() == ["r1", "r1", "r2"] and list(both.columns)[:2] == ["run_id", "policy"]


def test_md_escape_keeps_names_verbatim():
    assert views.md_escape("[x](http://e).csv") == "\\[x\\]\\(http://e\\)\\.csv"


def test_analysis_settings_round_trip_from_meta():
    from indicators.settings import AnalysisSettings

    saved = AnalysisSettings(k=4, feature_speeds_kph=(70.0, 80.0)).to_dict()
    s = views.analysis_settings(saved, k=2, choose_k="bic")
    assert (s.k, s.choose_k, s.feature_speeds_kph) == (2, "bic", (70.0, 80.0))


def test_reasons_markdown_lists_only_what_was_not_ingested():
    rows = pd.DataFrame(
        {"file": ["a.csv", "b_1.csv"], "status": ["ingested", "rejected"], "reason": ["", "bad header"]}
    )
    assert views.reasons_markdown(rows) == "- **b\\_1\\.csv** (rejected): bad header"


def test_crossval_picker_says_when_it_was_made_with_another_analysis():
    from laneprint.provenance import CURRENT, EARLIER, LABELS

    row = {
        "created_at": "2026-12-06T10:00",
        "target_kind": "style",
        "target": "Normal",
        "run_id": "r1",
        "reward": "decisions",
        "folds": 4,
    }
    assert LABELS[EARLIER] in views.crossval_label({**row, "analysis": LABELS[EARLIER]})
    assert views.crossval_label({**row, "analysis": LABELS[CURRENT]}) == views.crossval_label(row)


def test_each_page_names_the_next_step_once_its_own_is_done():
    assert views.next_step("data", has_recordings=False, has_analysis=False) is None
    assert "**Styles** page" in views.next_step("data", has_recordings=True, has_analysis=False)
    assert views.next_step("styles", has_recordings=True, has_analysis=False) is None
    assert "**Training** page" in views.next_step("styles", has_recordings=True, has_analysis=True)
    assert "**Personalise** page" in views.next_step("results", has_recordings=True, has_analysis=True)
    assert views.next_step("personalize", has_recordings=True, has_analysis=True) is None


def test_a_run_choosing_its_learner_shows_the_phase_and_the_time_left():
    """`auto`'s choice writes its phase and summed episodes to status.json: the Training page shows them
    (it read "starting the trainer" for minutes before)."""
    status = {
        "state": "running",
        "episode": 4000,
        "episodes": 12000,
        "started_at": "2026-12-08T10:00:00+00:00",
        "updated_at": "2026-12-08T10:00:30+00:00",
        "message": "choosing the learner: training 4 DQNs, trees 3/3",
    }
    doing = views.run_doing(status)
    assert "choosing the learner: training 4 DQNs" in doing and "about 60 s left" in doing
    assert "starting the trainer" in views.run_doing({**status, "episode": 0, "message": "training"})
    assert views.time_left({**status, "episode": 100}) == ""  # too early to say
