"""Per-driver lines by partial pooling (`driver_lines = "mixed"`) and `analyze --config`."""

import numpy as np
import pytest
from typer.testing import CliRunner

from indicators.mixed import mixed_fits
from indicators.settings import AnalysisSettings
from indicators.stats import Group
from laneprint.app.cli import app
from laneprint.options import Section, build, read_tables
from laneprint.errors import UserError


def groups(n_points: dict[str, int], seed: int = 0) -> list[Group]:
    """Drivers on lines t = A v + b with A around 0.25 and b around -1, noise 0.3 s."""
    rng = np.random.default_rng(seed)
    out = []
    for i, (drv, n) in enumerate(n_points.items()):
        v = rng.uniform(16, 25, n)
        out.append(Group(drv, "t_f", v, (0.25 + 0.02 * i) * v - 1.0 + rng.normal(0, 0.3, n), np.array(["ok"] * n)))
    return out


def test_rich_drivers_keep_their_line_and_few_presses_borrow():
    fits = mixed_fits(groups({"A": 60, "B": 60, "C": 60, "FEW": 3}))
    assert fits is not None
    assert fits["A"]["A"] == pytest.approx(0.25, abs=0.03) and fits["C"]["A"] == pytest.approx(0.29, abs=0.03)
    few = fits["FEW"]
    # among the population's slopes (a three-point OLS slope would be anywhere), its interval no narrower
    assert fits["A"]["A"] - 0.03 < few["A"] < fits["C"]["A"] + 0.03
    assert few["A_hi"] - few["A_lo"] >= 0.9 * (fits["A"]["A_hi"] - fits["A"]["A_lo"])


def test_one_driver_is_no_mixed_model():
    assert mixed_fits(groups({"A": 30})) is None


def test_config_table_checks_keys_and_types(tmp_path):
    good = tmp_path / "a.toml"
    good.write_text('[analysis]\ndriver_lines = "mixed"\nk = 4\nalpha = 1\nfeature_speeds_kph = [60, 90]\n')
    sec = Section("analysis", AnalysisSettings)
    s, given = build(sec, read_tables(good)["analysis"], {}, "here")
    assert (s.driver_lines, s.k, s.alpha, s.feature_speeds_kph) == ("mixed", 4, 1.0, (60, 90))
    assert given == {"driver_lines", "k", "alpha", "feature_speeds_kph"}
    for text, why in [
        ("[analysis]\nnope = 1\n", "has no setting 'nope'"),
        ('[analysis]\nk = "three"\n', "k must be int"),
        ("[analysis]\nk = [\n", "not valid TOML"),
        ("[analysis]\nfit_cancelled = 1\n", "fit_cancelled must be bool"),
        ("k = 3\n", "outside any table"),
        ("[analysys]\nk = 3\n", "did you mean analysis"),
    ]:
        bad = tmp_path / "b.toml"
        bad.write_text(text)
        with pytest.raises(UserError, match=why):
            build(sec, read_tables(bad).get("analysis", {}), {}, "here")


def test_analyze_config_refuses_in_one_line(tmp_path):
    bad = tmp_path / "c.toml"
    bad.write_text('[analysis]\ndriver_lines = "bayes"\n')
    ws = tmp_path / "ws"
    res = CliRunner().invoke(app, ["analyze", "-w", str(ws), "--config", str(bad)])
    assert res.exit_code == 1 and "Traceback" not in res.output
