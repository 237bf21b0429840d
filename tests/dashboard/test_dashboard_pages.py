"""Each page under Streamlit's AppTest, on an empty and on a sample workspace."""

import json

import pytest
from streamlit.testing.v1 import AppTest

from dashboard_support import APP, log_bytes, page_path

PAGES = ["data", "drivers", "styles", "training", "results"]


def run_page(name: str) -> AppTest:
    at = AppTest.from_file(page_path(name), default_timeout=60).run()
    assert not at.exception, [e.value for e in at.exception]
    return at


def style_table(at: AppTest):
    """The Styles page's members table (a static table, its text wraps), `style` a column."""
    return next(t.value.reset_index() for t in at.table if "typical driver" in t.value.columns)


def charts(at: AppTest) -> list[dict]:
    return [json.loads(el.proto.spec) for el in at.get("plotly_chart")]


@pytest.mark.parametrize("name", PAGES)
def test_page_on_empty_workspace(empty_ws, name):
    at = run_page(name)
    assert at.title[0].value == name.capitalize()
    if name != "training":
        assert at.info, "an empty workspace should say what to do first"


def test_navigation_runs_default_page(empty_ws):
    at = AppTest.from_file(str(APP), default_timeout=60).run()
    assert not at.exception
    assert at.title[0].value == "Data"


def test_data_page_lists_recordings_and_views_one(use_sample):
    at = run_page("data")
    assert at.subheader[1].value == "Recordings (6)"
    assert at.selectbox(key="recording").options[0].startswith("D01 / D01_S80")
    fig = charts(at)[0]
    assert fig["layout"]["yaxis"]["title"]["text"] == "ego speed [m/s]"


def test_drivers_page_shows_three_indicators_and_the_headway_kept(use_sample):
    at = run_page("drivers")
    assert at.selectbox(key="driver").value == "D01"
    groups = at.radio(key="indicator_group")
    paper = next(o for o in groups.options if o.startswith("The paper's three"))
    at = groups.set_value(paper).run()  # the page opens on the group the styles were read by
    figs = charts(at)
    assert len(figs) == 5  # three indicators, the headway kept in steady following, the correlation table
    for fig in figs[:4]:
        assert "[m/s]" in fig["layout"]["xaxis"]["title"]["text"]  # units on every axis
        assert "[" in fig["layout"]["yaxis"]["title"]["text"]
    kept = figs[3]
    assert kept["layout"]["yaxis"]["type"] == "log" and kept["layout"]["title"]["text"].startswith("D01: ")
    episodes = use_sample.read_table("analysis", "following")
    assert len(kept["data"][0]["x"]) == int((episodes["driver_id"] == "D01").sum())
    assert figs[4]["data"][0]["type"] == "table"
    at.selectbox(key="driver").set_value("D04").run()
    assert not at.exception and "D04" in at.markdown[0].value
    d04 = next(f for f in charts(at) if f["layout"]["title"]["text"].startswith("D04: time headway kept"))
    n = int((episodes["driver_id"] == "D04").sum())
    assert n > 0 and len(d04["data"][0]["x"]) == n  # every episode of its drives, and the level line
    assert any(a["text"].startswith("thw_follow ") for a in d04["layout"]["annotations"])


def test_styles_page_summary(use_sample):
    at = run_page("styles")
    summary = style_table(at)
    assert summary["drivers"].sum() == 6
    assert set(summary["style"]) <= {"Defensive", "Normal", "Aggressive"}
    # the headway each driver keeps over its drives, per episode on a log axis, with the level read
    kept = next(f for f in charts(at) if "steady following" in f["layout"]["title"]["text"])
    assert kept["layout"]["yaxis"]["type"] == "log"
    level = next(t for t in kept["data"] if t["name"] == "level (thw_follow)")
    assert len(level["x"]) >= 1 and all(0.3 < y < 10 for y in level["y"])
    title = kept["layout"]["title"]["text"]
    none = title.split("no episode: ")[1].split(", ") if "no episode: " in title else []
    drivers = use_sample.read_table("analysis", "styles")["driver_id"].astype(str)
    assert sorted([*level["x"], *none]) == sorted(drivers)  # every driver: a level, or named as having none


def test_results_page_compares_two_runs(use_sample):
    at = run_page("results")
    table = at.dataframe[0].value.set_index("policy")
    assert table.index[:2].tolist() == ["agent", "greedy"]  # + imitation when the evaluation has it
    assert table.index[-1] == "driver" and table.loc["driver", "recall at the presses [%]"] == 100.0
    figs = charts(at)
    assert "[s]" in figs[0]["layout"]["yaxis"]["title"]["text"]  # Fig. 10 has units
    compared = next(d.value for d in at.dataframe if "run_id" in d.value.columns)
    assert compared["run_id"].nunique() == 2


def test_training_page_defaults_from_table2(use_sample):
    at = run_page("training")
    assert at.number_input(key="episodes").value >= 1
    assert (
        at.selectbox(key="target_name").options == ["Defensive", "Normal", "Aggressive"]
        or len(at.selectbox(key="target_name").options) >= 2
    )
    assert at.dataframe[0].value["run_id"].tolist() == ["Normal-seed1", "Normal-seed0"]  # newest first
    assert at.number_input(key="hp_learning_rate").value == 0.005 and at.number_input(key="hp_gamma").value == 0.98


def test_upload_ingests_and_refuses_with_reasons(empty_ws, tmp_path):
    at = run_page("data")
    good = log_bytes(tmp_path, driver_id=None)
    at.file_uploader[0].set_value(
        [
            ("drive one.csv", good, "text/csv"),
            ("../../../escape.csv", log_bytes(tmp_path, driver_id="D05", seed=1), "text/csv"),
            ("empty.csv", b"", "text/csv"),
            ("notes.txt", b"hello", "text/plain"),
            ("garbage.mcap", b"not an mcap file at all", "application/octet-stream"),
        ]
    ).run()
    at.text_input(key="driver_id").set_value("D11").run()
    at.button(key="ingest").click().run()
    assert not at.exception, [e.value for e in at.exception]
    rows = at.dataframe[0].value.set_index("file")
    assert rows.loc["drive one.csv", "status"] == "ingested" and rows.loc["drive one.csv", "driver_id"] == "D11"
    assert rows.loc["../../../escape.csv", "status"] == "warning"  # the file names D05, not D11
    assert "D05" in rows.loc["../../../escape.csv", "reason"]
    assert rows.loc["empty.csv", "status"] == "refused" and "empty" in rows.loc["empty.csv", "reason"]
    assert rows.loc["notes.txt", "reason"].startswith("not a log")
    assert rows.loc["garbage.mcap", "status"] == "rejected" and rows.loc["garbage.mcap", "reason"]
    assert not list(empty_ws.root.rglob("garbage.mcap"))  # a rejected upload is not kept
    assert any("**garbage\\.mcap** (rejected): not an MCAP file" in m.value for m in at.markdown)
    assert at.warning, "a partly refused upload is a warning"
    saved = sorted(p.relative_to(empty_ws.root).parts[0] for p in empty_ws.root.rglob("escape.csv"))
    assert saved == ["uploads"]
    assert not (empty_ws.root.parent / "escape.csv").exists()
    assert at.subheader[1].value == "Recordings (2)"
    # the same bytes again: a duplicate, not a second recording
    at.file_uploader[0].set_value([("again.csv", good, "text/csv")]).run()
    at.button(key="ingest").click().run()
    assert at.dataframe[0].value["status"].tolist() == ["duplicate"]


@pytest.mark.slow
def test_styles_rerun_with_other_k(sample_ws, tmp_path, monkeypatch):
    import shutil

    from laneprint.workspace import Workspace

    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    at = run_page("styles")
    assert at.number_input(key="k").value == 3
    at.number_input(key="k").set_value(2)
    # how gaps and headways are read: the defaults shown, the other ways available by name
    assert at.selectbox(key="acceptance_fit").value == "trimmed" and at.checkbox(key="receding").value
    at.selectbox(key="acceptance_fit").set_value("median")
    at.checkbox(key="receding").uncheck()
    at.button[0].click().run()  # the form's "Run analysis"
    assert not at.exception, [e.value for e in at.exception]
    saved = ws.read_meta("analysis")["settings"]
    assert saved["k"] == 2 and saved["acceptance_fit"] == "median" and saved["max_receding_mps"] is None
    assert ws.read_table("analysis", "styles")["style"].nunique() == 2
    assert len(style_table(at)) == 2  # the page shows the new clusters, not cached old ones


@pytest.mark.slow
def test_two_runs_at_once_and_cancel(sample_ws, tmp_path, monkeypatch):
    """Launch a long and a short run from the form; the short one finishes while the long one
    runs, then Cancel stops the long one (the trainer checkpoints and marks it cancelled)."""
    import shutil
    import time

    from dashboard import jobs
    from laneprint.workspace import Workspace

    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    monkeypatch.setenv("LANEPRINT_DASHBOARD_POLL_S", "0.2")
    at = run_page("training")
    start = next(b for b in at.button if b.label == "Start training")
    at.number_input(key="episodes").set_value(100_000)
    start.click().run()
    at.number_input(key="episodes").set_value(200)
    at.number_input(key="hp_learning_starts").set_value(200)  # 200 episodes can learn from 200 transitions on
    at.number_input(key="seed").set_value(1)
    next(b for b in at.button if b.label == "Start training").click().run()
    assert not at.exception, [e.value for e in at.exception]
    launched = at.session_state["launched"]
    assert len(launched) == 2
    long_id, short_id = launched

    def state(rid):
        return jobs.run_status(ws, rid)["state"]

    deadline = time.monotonic() + 300  # a loaded CI machine runs 200 episodes in well over a minute
    while time.monotonic() < deadline and not (state(short_id) == "done" and state(long_id) == "running"):
        time.sleep(0.3)
    logs = f"short {short_id}:\n{jobs.log_tail(ws, short_id)}\nlong {long_id}:\n{jobs.log_tail(ws, long_id)}"
    assert (state(short_id), state(long_id)) == ("done", "running"), logs
    at.run()
    assert not at.exception
    cancel = next(b for b in at.button if b.key == f"cancel_{long_id}")
    cancel.click().run()
    while time.monotonic() < deadline and state(long_id) == "running":
        time.sleep(0.3)
    assert state(long_id) == "cancelled"
    # stopped while training: checkpointed; stopped while the default learner is chosen: nothing to keep yet
    message = jobs.run_status(ws, long_id).get("message") or ""
    assert (ws.runs_dir / long_id / "checkpoint.pt").exists() or "while choosing the learner" in message
    at.run()
    table = at.dataframe[0].value.set_index("run_id")
    assert table.loc[short_id, "state"] == "done" and table.loc[long_id, "state"] == "cancelled"


def test_too_large_upload_is_refused_with_a_hint(empty_ws, tmp_path, monkeypatch):
    monkeypatch.setenv("LANEPRINT_DASHBOARD_MAX_UPLOAD_MB", "0.001")  # 1 kB for the test
    at = run_page("data")
    at.file_uploader[0].set_value([("big.csv", b"t,ego_x\n" + b"0,0\n" * 600, "text/csv")]).run()
    at.button(key="ingest").click().run()
    assert not at.exception
    row = at.dataframe[0].value.iloc[0]
    assert row["status"] == "refused" and "laneprint ingest" in row["reason"]
    assert not list((empty_ws.root / "uploads").rglob("big.csv"))
    assert at.info  # still no recordings, the page keeps working


def test_stale_analysis_is_flagged(sample_ws, tmp_path, monkeypatch):
    import shutil

    from laneprint.workspace import Workspace

    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    assert not any("since this analysis ran" in i.value for i in run_page("drivers").info)
    shutil.rmtree(ws.recordings_dir / ws.recordings()["recording_id"].iloc[0])
    assert any("since this analysis ran" in i.value for i in run_page("drivers").info)


def test_training_for_a_driver_needs_an_analysis(empty_ws):
    at = run_page("training")
    assert not next(b for b in at.button if b.label == "Start training").disabled  # styles: Table 1 lines
    at.radio(key="target_kind").set_value("driver").run()
    assert next(b for b in at.button if b.label == "Start training").disabled
    assert "Nothing to train for yet" in at.info[0].value


def test_results_training_curves_run_only_once_opened(use_sample):
    at = run_page("results")
    run_id = at.selectbox(key="result_run").value
    assert not [c for c in charts(at) if "Fig. 9" in c["layout"].get("title", {}).get("text", "")]
    assert "Training curves (Fig. 9)" in [e.label for e in at.expander]
    at.session_state[f"fig9_open_{run_id}"] = True  # what opening the expander does
    at.run()
    assert not at.exception
    fig9 = [c for c in charts(at) if "Fig. 9" in c["layout"].get("title", {}).get("text", "")]
    assert len(fig9) == 1 and at.slider(key=f"smoothing_{run_id}").value == 0.95


def test_results_page_draws_a_closed_loop_drive_beside_its_drivers(empty_ws):
    import numpy as np
    import pandas as pd

    from rl.drive.fidelity import compare_values, rate_comparison

    rng = np.random.default_rng(0)
    drivers = pd.DataFrame({"driver_id": ["a"], "changes": [30], "left": [15], "right": [15], "km": [10.0]})
    fid = {
        "tolerance": 0.2,
        "medians_in_iqr": "1 of 1",
        "drivers": ["a"],
        "rate": rate_comparison({"changes": 31, "left": 15, "right": 16, "km": 10.0}, drivers),
        "indicators": {"t_f": compare_values(rng.normal(8, 1, 40), rng.normal(8, 1, 90), rng)},
    }
    folder = empty_ws.root / "drives" / "normal-s1"
    folder.mkdir(parents=True)
    # one section as `laneprint drive` reports it, the other as a drive reported before lane changes were
    # attributed one by one (its counts only)
    sections = [
        {
            "speed_limit_kph": 80.0,
            "lane_changes": 12,
            "agent_changes": 0,
            "rule_changes": 12,
            "return_changes": 4,
            "made_by": {"agent": 0, "rule_held_back": 8, "rule_return": 4, "unattributed": 0},
        },
        {"speed_limit_kph": 90.0, "lane_changes": 19, "agent_changes": 3, "rule_changes": 16, "return_changes": 6},
    ]
    totals = {"lane_changes": 31, "agent_changes": 3, "rule_changes": 28, "return_changes": 10}
    (folder / "drive.json").write_text(
        json.dumps({"run_id": "normal", "lanes": 3, "seed": 1, "fidelity": fid, "sections": sections, "totals": totals})
    )
    at = run_page("results")
    assert any("Closed-loop drives in SUMO (1)" in s.value for s in at.subheader)
    assert "3 lanes, seed 1, 3.10 /km (drivers 3.00)" in at.selectbox(key="drive_pick").options[0]
    (fig,) = [c for c in charts(at) if "beside its drivers" in c["layout"]["title"]["text"]]
    assert len(fig["data"]) == 4
    # who made each lane change: the agent, or the rule and which part of it, per section and in total
    assert any(
        "Who changed lane: 31 lane changes: the agent 3, the rule 28 (held back 18, return 10)" in m.value
        for m in at.markdown
    )
    who = next(d.value for d in at.dataframe if "by the agent" in d.value.columns)
    assert who["section"].tolist() == ["80 km/h", "90 km/h", "total"]
    assert who["rule: held back"].tolist() == [8, 10, 18] and who["by the agent"].tolist() == [0, 3, 3]
    assert any("when a slower leader has held the ego back" in c.value for c in at.caption)


def test_personalize_page_starts_from_the_cli_default(use_sample):
    from typer.main import get_command

    from laneprint.app.cli import app
    from rl.personalize.settings import PersonalizeSettings

    at = AppTest.from_file(page_path("personalize"), default_timeout=120).run()
    assert not at.exception, [e.value for e in at.exception]
    radio = at.radio(key="p_base")
    opts = {o for p in get_command(app).commands["personalize"].params for o in p.opts}
    assert "--from" in opts  # the option the caption names; its default is the settings' own
    assert radio.value == PersonalizeSettings().base == radio.options[0]
    assert any(f"--from {radio.value}" in c.value for c in at.caption)


@pytest.mark.slow
def test_a_tree_run_from_the_form_trains_and_shows(sample_ws, tmp_path, monkeypatch):
    """Learner 'trees' on the form launches `train --learner trees`; the run finishes and the
    Results page shows it."""
    import shutil
    import time

    from dashboard import jobs
    from laneprint.workspace import Workspace

    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    at = run_page("training")
    at.selectbox(key="learner").set_value("trees").run()
    assert at.number_input(key="episodes").disabled
    next(b for b in at.button if b.label == "Start training").click().run()
    assert not at.exception, [e.value for e in at.exception]
    (run_id,) = at.session_state["launched"]
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and jobs.run_status(ws, run_id)["state"] in jobs.ACTIVE_STATES:
        time.sleep(0.5)
    assert jobs.run_status(ws, run_id)["state"] == "done", jobs.log_tail(ws, run_id)
    config = json.loads((ws.root / "runs" / run_id / "config.json").read_text())
    assert config["learner"] == "trees"
    results = run_page("results")
    assert not results.exception, [e.value for e in results.exception]
    assert run_id in results.selectbox(key="result_run").options


def test_the_learner_follows_the_reward_on_the_training_form(sample_ws, monkeypatch):
    """'auto' is the form's default learner on the decisions reward; a reward the trees cannot fit
    leaves only the DQN, even after the trees were picked, without an error on the page."""
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(sample_ws.root))
    at = run_page("training")
    assert at.selectbox(key="learner").value == "auto"
    at.selectbox(key="learner").set_value("trees").run()
    at.selectbox(key="reward").set_value("timing").run()
    assert not at.exception
    assert at.selectbox(key="learner").options == ["dqn"] and at.selectbox(key="learner").value == "dqn"
