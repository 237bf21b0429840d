"""Honest labels of a personalised run (issue 48): what was scored, what was done, and a finished
personalisation showing its result and link instead of "(0/?)" and Cancel."""

from streamlit.testing.v1 import AppTest

from dashboard import views
from dashboard_support import page_path, write_fake_run
from laneprint.workspace import atomic_write_json

CONFIG = {
    "kind": "personalized",
    "decisions": 10,
    "decisions_available": 42,
    "base": {"from": "blend", "chosen": "blend"},
    "target": {"kind": "driver", "name": "D03"},
    "reward": "timing",
    "lines_source": "analysis",
    "seed": 0,
}
STATUS = {
    "state": "done",
    "episode": 0,
    "episodes": 0,
    "message": "the blend of 3 agents weighted by 10 decisions as it is",
}


def test_labels_say_what_was_scored_and_done():
    heading, caption = views.evaluation_heading(
        {"scored_on": "held out: the 32 decisions not given", "split": {"given": 10, "held_out": 32}}
    )
    assert "held out: the 32 decisions not given" in heading
    assert "first 10 decisions" in caption and "imitation classifier fitted on the same" in caption
    assert views.evaluation_heading({})[0].startswith("In-sample")
    header = views.run_header("p1", CONFIG, STATUS)
    assert "0 episodes" not in header and "first 10 of 42 decisions" in header and "not fine-tuned" in header
    assert "(0/?)" not in views.personalize_progress("p1", {"state": "running", "message": "evaluating"})[1]
    done = views.personalize_done(
        "p1",
        STATUS,
        {"later_decisions": {"n_decisions": 32, "balanced_accuracy": 0.8, "balanced_accuracy_ci": [0.7, 0.9]}},
    )
    assert "Held out (the 32 decisions not given): balanced accuracy 80.0 % [70.0, 90.0]" in done


def test_a_finished_personalisation_shows_its_result_and_link(empty_ws):
    ws = empty_ws.ensure()
    folder = write_fake_run(ws, "p1")
    atomic_write_json(folder / "config.json", {"run_id": "p1", **CONFIG})
    atomic_write_json(folder / "status.json", STATUS)
    atomic_write_json(
        folder / "personalize.json",
        {
            "run_id": "p1",
            "driver": "D03",
            "decisions": 10,
            "decisions_available": 42,
            "base": {"from": "blend"},
            "style": {"style": "Normal", "confidence": 0.9},
            "later_decisions": {"n_decisions": 32, "balanced_accuracy": 0.8, "balanced_accuracy_ci": [0.7, 0.9]},
        },
    )
    at = AppTest.from_file(page_path("personalize"), default_timeout=120)
    at.session_state["p_launched"] = ["p1"]
    at.run()
    assert not at.exception, [e.value for e in at.exception]
    assert any("p1 done" in s.value and "32 decisions not given" in s.value for s in at.success)
    assert any("results?run=p1" in m.value for m in at.markdown)
    assert not any(b.key == "p_cancel_p1" for b in at.button)
    table = next(d.value for d in at.dataframe if "analysis" in d.value.columns)
    assert table.loc[0, "analysis"] == "analysis unknown"  # recorded before runs named their analysis
    assert table.loc[0, "held out: decisions not given"] == 32


def test_progress_names_the_phase_and_the_time_it_has_left():
    status = {
        "state": "running",
        "episode": 300,
        "episodes": 1200,
        "message": "training the base agent (Normal)",
        "phase": 2,
        "phases": 4,
        "phase_name": "training the base agent (Normal)",
        "started_at": "2026-11-22T00:00:00+00:00",
        "phase_started_at": "2026-11-22T00:02:00+00:00",
        "updated_at": "2026-11-22T00:03:00+00:00",
    }
    frac, text = views.personalize_progress("p1", status)
    assert frac == 0.25
    # 60 s for a quarter of this phase (not the 3 min since the run started): about 3 min left
    assert text == "p1: phase 2 of 4: training the base agent (Normal) (300/1,200 episodes, about 3 min left)"
    assert "starting" in views.personalize_progress("p1", {"state": "starting"})[1]


def test_the_command_lines_bar_starts_afresh_each_phase(monkeypatch):
    from laneprint import cliutil

    resets = []
    monkeypatch.setattr(cliutil.Progress, "reset", lambda self, task, **kw: resets.append(kw["total"]))
    with cliutil.progress_bar() as bar:
        for done in range(0, 50, 10):
            bar(done, 50, "phase 2/4: base: episode")
        bar(0, 40, "phase 3/4: personalised: episode 0")
        bar(10, 40, "phase 3/4: personalised: episode 10")
    assert resets == [50, 40]  # once when the first total is known, once when the next phase starts
