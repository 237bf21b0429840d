"""The documentation: reference pages generated from the app, and a site that builds --strict."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from laneprint.app.reference_docs import pages

ROOT = Path(__file__).resolve().parents[2]


def test_reference_pages_match_the_app():
    """Regenerate with `python -m laneprint.app.reference_docs` when a command or setting changes."""
    for name, text in pages().items():
        committed = (ROOT / "docs" / "reference" / name).read_text(encoding="utf-8")
        assert committed == text, f"docs/reference/{name} is out of date: python -m laneprint.app.reference_docs"


def test_readme_and_reference_carry_no_issue_numbers():
    for path in [ROOT / "README.md", *(ROOT / "docs" / "reference").glob("*.md")]:
        text = path.read_text(encoding="utf-8")
        assert not re.search(r"\bissue \d+", text, re.I), path
    assert len((ROOT / "README.md").read_bytes()) <= 15_000


@pytest.mark.slow
def test_site_builds_strict(tmp_path):
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent)) or shutil.which("mkdocs")
    assert mkdocs, "mkdocs is in the test extra"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    res = subprocess.run(
        [mkdocs, "build", "--strict", "-q", "-d", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert (tmp_path / "site" / "reference" / "cli" / "index.html").exists()


def test_a_benchmarks_result_file_of_any_layout_is_rendered(tmp_path, monkeypatch):
    """`benchmarks/results_file.write_result`'s files: the common keys in the head, figures listed, records as tables."""
    import importlib.util

    import laneprint.app.reference_docs as ref

    spec = importlib.util.spec_from_file_location("results_file", ROOT / "benchmarks" / "results_file.py")
    results_file = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(results_file)
    monkeypatch.setattr(results_file, "RESULTS", tmp_path)
    monkeypatch.setattr(ref, "RESULTS", tmp_path)
    import numpy as np

    results_file.write_result(
        "speed",
        {
            "median_s": np.float64(1.23456),
            "n": np.int64(3),
            "by": {"csv": {"mb": 2.5}},
            "rows": [{"format": "csv", "what": "a|b"}, {"format": "mcap", "x": None}],
        },
        ["--reps", "1"],
    )
    page = ref.results_page()
    assert "## speed" in page and "--reps 1`" in page and results_file.machine() in page
    assert "- median_s: 1.235" in page and "- n: 3" in page and "- by.csv.mb: 2.5" in page
    assert "| format | what | x |" in page and "| csv | a\\|b |  |" in page and "| mcap |  | - |" in page
    with pytest.raises(ValueError, match="commit"):
        results_file.write_result("bad", {"commit": "x"})


#: Where the documentation may carry dates: the changelog, the measurement history kept out of the site,
#: and the results pages (each result file names the date and commit of its measurement).
DATED = ("CHANGELOG.md",)


def _user_documents() -> dict[str, str]:
    """README.md and every page of the site, the changelog, the history and the results pages aside."""
    docs = {"README.md": (ROOT / "README.md").read_text(encoding="utf-8")}
    for path in sorted((ROOT / "docs").rglob("*.md")):
        rel = path.relative_to(ROOT / "docs")
        if rel.parts[0] == "history" or path.name in DATED or path.name.startswith("results"):
            continue
        docs[f"docs/{rel}"] = path.read_text(encoding="utf-8")
    return docs


def _help_texts() -> dict[str, str]:
    """`laneprint --help`, every command's `--help`, and the help of its hidden options (the config reference's)."""
    import typer
    from typer.testing import CliRunner

    from laneprint.app.cli import app

    group = typer.main.get_command(app)
    texts = {"laneprint --help": CliRunner().invoke(app, ["--help"], terminal_width=200).output}
    for name, cmd in group.commands.items():  # type: ignore[attr-defined]
        texts[f"laneprint {name} --help"] = CliRunner().invoke(app, [name, "--help"], terminal_width=200).output
        texts[f"laneprint {name}: every option's help"] = "\n".join(getattr(p, "help", None) or "" for p in cmd.params)
    return texts


#: An issue number, or a date (2026-01-31, 2026-01, "January 31", "31 January", "Jan 31, 2026").
UNDATED = re.compile(
    r"\bissues? #?\d+|(?<![\w/.-])#\d{2,}\b|\b(19|20)\d\d-[01]\d(-[0-3]\d)?\b"
    r"|\b(jan|feb|mar|apr|may|jun|jul|aug|sep|sept|oct|nov|dec)[a-z]*\.? [0-3]?\d(st|nd|rd|th)?\b(,? \d{4})?"
    r"|\b[0-3]?\d (january|february|march|april|may|june|july|august|september|october|november|december)\b",
    re.I,
)


def test_no_issue_numbers_and_no_dates_in_the_readme_the_site_or_the_help():
    found = [
        (where, m.group(0))
        for where, text in {**_user_documents(), **_help_texts()}.items()
        for m in UNDATED.finditer(text)
    ]
    assert not found, found
    assert UNDATED.search("see issue 12") and UNDATED.search("measured 2026-01-31") and UNDATED.search("on March 3")


def test_the_readme_starts_with_the_two_set_up_commands():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.encode("utf-8")) <= 15_000
    shells = re.findall(r"```(?:sh|bash|console)\n(.*?)```", text, re.S)
    assert len(shells) >= 2
    install, tests = (" ".join(s.split()) for s in shells[:2])
    assert "pip install -e ." in install and "laneprint run sample_logs" in install
    assert "pip install -e '.[test]'" in tests and "pytest" in tests


def test_the_mapping_guide_is_one_click_from_the_readme():
    """A user with an MCAP from their own simulator: README -> 'Your own study' -> its 'Mapping files'."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "](docs/your-own-study.md)" in readme
    guide = (ROOT / "docs" / "your-own-study.md").read_text(encoding="utf-8")
    for heading in ("## Mapping files", "## Logs of ROS 2 and protobuf stacks", "### Worked example"):
        assert heading in guide


def test_the_guides_mappings_load_and_are_the_ones_the_stack_tests_ingest(tmp_path):
    """Every TOML block of the mapping guide is a valid mapping; its worked examples are, key for key, the
    mappings `tests/ingest/test_ingest_mcap_decoded.py` ingests real ROS 2 and protobuf MCAP files with."""
    import tomllib

    from ingest.mapping import load_mapping
    from tests.support.stack_examples import PROTOBUF_MAPPING, ROS2_MAPPING

    guide = (ROOT / "docs" / "your-own-study.md").read_text(encoding="utf-8")
    blocks = {b.splitlines()[0].lstrip("# ").split()[0]: b for b in re.findall(r"```toml\n(.*?)```", guide, re.S)}
    assert {"my_rig.toml", "ros2_stack.toml", "protobuf_stack.toml"} <= blocks.keys()
    for name, text in blocks.items():
        (tmp_path / name).write_text(text, encoding="utf-8")
        load_mapping(tmp_path / name)  # an unknown key would raise
    assert tomllib.loads(blocks["ros2_stack.toml"]) == tomllib.loads(ROS2_MAPPING)
    assert tomllib.loads(blocks["protobuf_stack.toml"]) == tomllib.loads(PROTOBUF_MAPPING)


#: Terms the commands use that the glossary must define (its bold entries).
GLOSSARY_TERMS = (
    "family",
    "dwell",
    "pace",
    "section",
    "held-back",
    "approach",
    "not-yet state",
    "typical driver",
    "decision",
    "style",
    "reference lines",
    "greedy",
    "in-sample",
    "held out",
    "fleet",
    "workspace",
    "learner",
    "formulation",
    "reading",
    "config file",
    "lag",
    "undo check",
    "confidence",
    "imitation classifier",
    "balanced accuracy",
)


def test_the_glossary_defines_every_term_the_commands_use():
    text = (ROOT / "docs" / "glossary.md").read_text(encoding="utf-8")
    entries = [e.lower() for e in re.findall(r"^\*\*(.+?)\*\*\n:", text, re.M)]
    missing = [t for t in GLOSSARY_TERMS if not any(t in e for e in entries)]
    assert not missing, missing


def test_every_environment_variable_is_documented():
    """Every `LANEPRINT_*` name in the product's code (and each ingest limit's) is on the environment page."""
    from dataclasses import fields

    from ingest.limits import IngestLimits, env_var
    from laneprint.app.reference_docs import environment_variables

    names = {env_var(f.name) for f in fields(IngestLimits)}
    for package in ("laneprint", "ingest", "indicators", "clustering", "rl", "dashboard"):
        for path in (ROOT / package).rglob("*.py"):
            names |= set(re.findall(r"\bLANEPRINT_[A-Z0-9_]*[A-Z0-9]\b", path.read_text(encoding="utf-8")))
    page = (ROOT / "docs" / "reference" / "environment.md").read_text(encoding="utf-8")
    assert not names - set(environment_variables()), names - set(environment_variables())
    assert all(f"`{n}`" in page for n in names)


def test_the_command_reference_lists_exactly_the_visible_options():
    """The page's rows of each command are its options shown in --help: one added, hidden or renamed fails."""
    import typer

    from laneprint.app.cli import app

    page = (ROOT / "docs" / "reference" / "cli.md").read_text(encoding="utf-8")
    sections = dict(re.findall(r"^## laneprint (\S+)\n(.*?)(?=^## |\Z)", page, re.S | re.M))
    group = typer.main.get_command(app)
    assert set(sections) == set(group.commands)  # type: ignore[attr-defined]
    for name, cmd in group.commands.items():  # type: ignore[attr-defined]
        shown = {
            p.opts[0]
            for p in cmd.params
            if p.param_type_name == "option" and p.name != "help" and not getattr(p, "hidden", False)
        }
        rows = set(re.findall(r"^\| `(--?[\w-]+)`", sections[name], re.M))
        assert rows == shown, (name, rows ^ shown)


def test_a_result_file_lands_on_its_topic_page(tmp_path, monkeypatch):
    import json

    import laneprint.app.reference_docs as ref

    monkeypatch.setattr(ref, "RESULTS", tmp_path)
    (tmp_path / "fleet.json").write_text(
        json.dumps({"command": "fleet.py --drivers 10", "commit": "abc", "date": "d", "machine": "m", "agents": 10})
    )
    (tmp_path / "ingest_stacks.json").write_text(json.dumps({"command": "ingest_stacks.py", "rows": []}))
    pages = ref.results_pages()
    assert set(pages) == {"results.md", *(t[0] for t in ref.RESULT_TOPICS)}
    assert (
        "## fleet" in pages["results-speed.md"]
        and "`python benchmarks/fleet.py --drivers 10`" in pages["results-speed.md"]
    )
    assert "## ingest_stacks" in pages["results-ingest.md"] and "## fleet" not in pages["results.md"]
    assert "`python benchmarks/dashboard.py`" in pages["results-dashboard.md"]  # no file yet: who writes one


def test_every_config_key_is_documented():
    """Every key a `--config` file takes: each settings table's fields and each command table's options."""
    import dataclasses
    import typing

    import typer

    from laneprint.app.cli import app
    from laneprint.app.reference_docs import command_keys
    from laneprint.options import SECTIONS

    page = (ROOT / "docs" / "reference" / "config.md").read_text(encoding="utf-8")
    tables = dict(re.findall(r"^## \[(\w+)\]\n(.*?)(?=^##+ |\Z)", page, re.S | re.M))
    missing = [
        f"[{t}] {f.name}"
        for t, cls in SECTIONS.items()
        for f in dataclasses.fields(cls)
        if f.init
        and not dataclasses.is_dataclass(typing.get_type_hints(cls)[f.name])  # a nested table
        and f"| `{f.name}` |" not in tables.get(t, "")
    ]
    for name, cmd in typer.main.get_command(app).commands.items():  # type: ignore[attr-defined]
        keys = [key for key, _ in command_keys(cmd)]
        section = re.search(rf"^### \[{name}\]\n(.*?)(?=^##+ |\Z)", page, re.S | re.M)
        missing += [f"[{name}] {k}" for k in keys if not section or f"| `{k}` |" not in section.group(1)]
    assert tables and not missing, missing


def test_the_onnx_guides_code_builds_the_observation_the_policy_was_trained_on():
    """The ONNX how-to's first Python block, run as a vehicle stack would (policy.json's `inputs` and raw
    measurements), gives laneprint's own observation for every observation layout."""
    import numpy as np

    from rl.problem.env import EnvConfig, observation, sample_scenes
    from rl.problem.observation import observation_spec
    from rl.settings import OBSERVATIONS
    from tests.support.rl_workspaces import raw_measurements

    guide = (ROOT / "docs" / "howto" / "onnx.md").read_text(encoding="utf-8")
    code = re.findall(r"```python\n(.*?)```", guide, re.S)[0]
    names: dict = {}
    exec(compile(code, "docs/howto/onnx.md", "exec"), names)  # noqa: S102 - the guide's own code
    for name in OBSERVATIONS:
        cfg = EnvConfig(observation=name, nb_present_prob=0.5, nb_gap0_m=(-3.0, 200.0))
        scenes = sample_scenes(np.random.default_rng(5), cfg, 200)
        scenes.f_present[::7] = False
        doc = {"inputs": observation_spec(cfg)}
        raws = raw_measurements(scenes, cfg)
        for raw, left in zip(raws, scenes.left):
            raw["target lane side"] = "left" if left else None
        rebuilt = np.concatenate([names["observation"](doc, raw) for raw in raws])
        np.testing.assert_allclose(rebuilt, observation(scenes, cfg), atol=1e-6, err_msg=name)


@pytest.mark.slow  # builds the site: ~4 s
def test_every_dashboard_help_link_opens_a_page_and_anchor_of_the_site_it_serves(tmp_path):
    """The dashboard's "More:" links (`dashboard.docs_site.LINKS`) against the site as the dashboard builds and
    serves it (`--no-directory-urls`, one .html file per page): each page is a file, each anchor a heading id."""
    from dashboard import docs_site

    site = tmp_path / "docs"
    assert docs_site.build(site=site) is None
    assert docs_site.built(site) and not docs_site.stale(site)
    missing = []
    for key in docs_site.LINKS:
        file, anchor = docs_site.target(key)
        page = site / file
        if not page.is_file():
            missing.append(f"{key}: {file}")
        elif anchor and f'id="{anchor}"' not in page.read_text(encoding="utf-8"):
            missing.append(f"{key}: {file}#{anchor}")
    assert not missing, missing
    assert docs_site.url("learners") == "app/static/docs/concepts/agents.html#the-learners"
