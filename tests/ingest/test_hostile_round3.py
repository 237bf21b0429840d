"""Hostile input, third round: small generated logs that are well formed but not physical, and MCAPs
that declare a channel twice. Each is refused with one line or kept with a warning that says what
was changed, never taken silently as a driver; each in under 5 s and 600 MB, without a traceback."""

from __future__ import annotations

import json
import resource
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ingest.logformat import METADATA_NAME, TOPIC_BUTTON, TOPIC_EGO, TOPIC_TRAFFIC
from ingest.pipeline import ingest_paths
from ingest.writers import write_csv, write_mcap
from laneprint.workspace import Workspace
from tests.ingest.conftest import make_recording

MAX_SECONDS = 5.0
MAX_GROWTH_MB = 600.0  # per file: the growth in this process, the peak in a fresh one


def _status_mb(key: str) -> float | None:
    try:
        with open("/proc/self/status") as f:
            return next((int(line.split()[1]) / 1024 for line in f if line.startswith(key + ":")), None)
    except OSError:
        return None


def _peak_mb() -> float:
    """The process's resident memory from now on [MB]: its current size, the peak since (`_grown_mb`) counted
    from here on. On Linux the peak (VmHWM) is reset to the current size first, so a case is measured
    alone; elsewhere the process's lifetime peak stands in (a case then shows only what exceeds it)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return _status_mb("VmRSS") or 0.0


def _grown_mb(before: float) -> float:
    """How far the resident memory rose above `before` (`_peak_mb()`'s) at its peak since [MB]."""
    peak = _status_mb("VmHWM")
    return (peak if peak is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024) - before


def ingest_one(path: Path, ws_root: Path, **kwargs):
    """Ingest one generated file: its FileResult, checked for time and memory."""
    before, t0 = _peak_mb(), time.perf_counter()
    report = ingest_paths([path], Workspace(ws_root), **kwargs)
    assert time.perf_counter() - t0 < MAX_SECONDS
    assert _grown_mb(before) < MAX_GROWTH_MB
    (res,) = report.files
    for line in [res.reason, *res.warnings]:
        assert "\n" not in line and "Traceback" not in line and "please report" not in line
    return res


# --- generated recordings ----------------------------------------------------------------------


def _ego_copy(meta, ego, traffic):
    """The ego listed among its own traffic, 1 m ahead at its own speed."""
    copy = pd.DataFrame(
        {
            "t_s": ego["t_s"],
            "vehicle_id": "me",
            "x_m": ego["ego_x_m"] + 1.0,
            "y_m": ego["ego_y_m"],
            "v_mps": ego["ego_v_mps"],
            "lane": ego["ego_lane"],
            "length_m": 4.5,
        }
    )
    return (
        meta,
        ego,
        pd.concat([traffic, copy], ignore_index=True).sort_values(["t_s", "vehicle_id"], ignore_index=True),
    )


def _static_ego(meta, ego, traffic):
    ego = ego.assign(ego_x_m=100.0, ego_v_mps=30.0)
    return meta, ego, traffic.iloc[0:0]


def _toggling(meta, ego, traffic):
    ego = ego.copy()
    ego["lc_button"] = np.arange(len(ego)) % 2 == 1
    ego["lc_direction"] = None
    return meta, ego, traffic


def _bounce(meta, ego, traffic):
    ego = ego.copy()
    i = int(np.flatnonzero(ego["lc_button"].to_numpy())[0])
    ego.loc[i + 3, "lc_button"] = False  # the first press released for one sample (50 Hz): a bounce
    return meta, ego, traffic


def _one_sample(meta, ego, traffic):
    ego = ego.iloc[:1].copy()
    ego["lc_button"] = True
    return meta, ego, traffic[traffic["t_s"] == 0.0]


def _limit(value):
    def change(meta, ego, traffic):
        return dict(meta, speed_limit_kph=value), ego, traffic

    return change


def _fast_presses(meta, ego, traffic):
    """A press every 0.5 s for 20 s: each one slow enough, far too many for decisions."""
    meta, ego, traffic = make_recording(seconds=20.0, hz=10)
    ego = ego.copy()
    ego["lc_button"] = np.arange(len(ego)) % 5 == 0
    ego["lc_direction"] = None
    return meta, ego, traffic


CASES = {
    # name: (change, format, expected status, text in the reason or warnings)
    "ego listed among its traffic (csv)": (_ego_copy, "csv", "warning", "ego listed among its own traffic"),
    "ego listed among its traffic (mcap)": (_ego_copy, "mcap", "warning", "ego listed among its own traffic"),
    "static ego with a speed (csv)": (_static_ego, "csv", "rejected", "does not follow the speed"),
    "static ego with a speed (mcap)": (_static_ego, "mcap", "rejected", "does not follow the speed"),
    "button toggles every sample (csv)": (_toggling, "csv", "rejected", "faster than a person presses"),
    "button toggles every sample (mcap)": (_toggling, "mcap", "rejected", "faster than a person presses"),
    "a press every half second": (_fast_presses, "csv", "rejected", "faster than a person presses"),
    "a bouncing press": (_bounce, "csv", "warning", "bouncing button"),
    "one sample with a press (csv)": (_one_sample, "csv", "rejected", "one sample only"),
    "one sample with a press (mcap)": (_one_sample, "mcap", "rejected", "one sample only"),
    "speed limit inf (csv)": (_limit(float("inf")), "csv", "rejected", "not a finite number"),
    "speed limit inf (mcap)": (_limit(float("inf")), "mcap", "rejected", "not a finite number"),
    "speed limit -80 (csv)": (_limit(-80), "csv", "rejected", "not a road's"),
    "speed limit -80 (mcap)": (_limit(-80), "mcap", "rejected", "not a road's"),
    "speed limit 5000 (csv)": (_limit(5000), "csv", "rejected", "not a road's"),
    "speed limit 0 (mcap)": (_limit(0), "mcap", "rejected", "not a road's"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_not_physical_is_refused_or_warned(tmp_path, name):
    change, fmt, status, text = CASES[name]
    meta, ego, traffic = change(*make_recording())
    path = tmp_path / f"case.{fmt}"
    (write_csv if fmt == "csv" else write_mcap)(path, meta, ego, traffic)
    res = ingest_one(path, tmp_path / "ws")
    assert res.status == status, (res.reason, res.warnings)
    assert text in (res.reason + " ".join(res.warnings))


def test_ego_copy_is_dropped_from_the_stored_traffic(tmp_path):
    meta, ego, traffic = _ego_copy(*make_recording())
    write_csv(tmp_path / "copy.csv", meta, ego, traffic)
    res = ingest_one(tmp_path / "copy.csv", tmp_path / "ws")
    _, _, stored = Workspace(tmp_path / "ws").load_recording(res.recording_id)
    assert "me" not in set(stored["vehicle_id"]) and {"a", "b", "c12"} <= set(stored["vehicle_id"])


def test_a_plain_recording_has_no_plausibility_warning(tmp_path):
    write_csv(tmp_path / "ok.csv", *make_recording())
    res = ingest_one(tmp_path / "ok.csv", tmp_path / "ws")
    assert res.status == "ingested", res.warnings


def _collision(meta, ego, traffic):
    """Vehicle 'z' drives 40 m ahead in the next lane, then 2 m ahead of the ego in its lane for 0.2 s."""
    hit = ego[(ego["t_s"] >= 2.0) & (ego["t_s"] < 2.2)]
    crash = pd.DataFrame(
        {
            "t_s": hit["t_s"],
            "vehicle_id": "z",
            "x_m": hit["ego_x_m"] + 2.0,
            "y_m": hit["ego_y_m"],
            "v_mps": hit["ego_v_mps"],
            "lane": hit["ego_lane"],
            "length_m": 4.5,
        }
    )
    before = pd.DataFrame(
        {
            "t_s": ego["t_s"][ego["t_s"] < 2.0],
            "vehicle_id": "z",
            "x_m": ego["ego_x_m"][ego["t_s"] < 2.0] + 40.0,
            "y_m": 0.0,
            "v_mps": ego["ego_v_mps"][ego["t_s"] < 2.0],
            "lane": 2,
            "length_m": 4.5,
        }
    )
    return (
        meta,
        ego,
        pd.concat([traffic, before, crash], ignore_index=True).sort_values(["t_s", "vehicle_id"], ignore_index=True),
    )


def test_a_collision_is_kept_with_a_warning(tmp_path):
    write_csv(tmp_path / "crash.csv", *_collision(*make_recording()))
    res = ingest_one(tmp_path / "crash.csv", tmp_path / "ws")
    assert res.status == "warning" and any("a collision or wrong positions; kept" in w for w in res.warnings)


# --- MCAPs written record by record --------------------------------------------------------------


def _raw_mcap(path: Path, records: list[tuple[str, int, str | None, int, bytes]], meta: dict) -> None:
    """An MCAP from (kind, channel id, topic, log time, data) records in order, written without chunks so
    that a Channel record may appear twice with another topic ('channel'), or a message ('message')."""
    from mcap.records import Channel, Footer, Header, Message, Metadata, DataEnd
    from mcap.data_stream import RecordBuilder

    out = bytearray(b"\x89MCAP0\r\n")

    def emit(rec) -> None:
        rb = RecordBuilder()
        rec.write(rb)
        out.extend(rb.end())

    emit(Header(profile="", library="test"))
    emit(Metadata(name=METADATA_NAME, metadata=meta))
    seq = 0
    for kind, cid, topic, ts, data in records:
        if kind == "channel":
            emit(Channel(id=cid, topic=topic or "", message_encoding="json", schema_id=0, metadata={}))
        else:
            emit(Message(channel_id=cid, sequence=seq, log_time=ts, publish_time=ts, data=data))
            seq += 1
    emit(DataEnd(data_section_crc=0))
    emit(Footer(summary_start=0, summary_offset_start=0, summary_crc=0))
    out.extend(b"\x89MCAP0\r\n")
    path.write_bytes(bytes(out))


def _samples(n: int = 60, button: int | None = 3, press_after_ns: int | None = None):
    recs = []
    for i in range(n):
        ts = 1_000_000_000 + i * 100_000_000
        recs.append(("message", 1, None, ts, json.dumps({"x": 100 + 2.5 * i, "v": 25.0, "lane": 0}).encode()))
        recs.append(("message", 2, None, ts, b'{"vehicles":[]}'))
        if button is not None and i in (10, 11, 30, 31):
            recs.append(
                ("message", button, None, ts, json.dumps({"pressed": i in (10, 30), "direction": "left"}).encode())
            )
    if press_after_ns is not None:
        last = 1_000_000_000 + (n - 1) * 100_000_000
        recs.append(("message", button, None, last + press_after_ns, b'{"pressed":true,"direction":"left"}'))
    return recs


HEAD = [("channel", 1, TOPIC_EGO, 0, b""), ("channel", 2, TOPIC_TRAFFIC, 0, b""), ("channel", 3, TOPIC_BUTTON, 0, b"")]


def test_mcap_channel_id_declared_twice_with_another_topic_is_refused(tmp_path):
    redeclared = HEAD + [("channel", 3, "/other/topic", 0, b"")]
    _raw_mcap(tmp_path / "twice.mcap", redeclared + _samples(), {"driver_id": "D1", "session_id": "s1"})
    res = ingest_one(tmp_path / "twice.mcap", tmp_path / "ws")
    assert res.status == "rejected" and "channel id 3 is declared twice" in res.reason, res.reason


def test_mcap_channel_declared_twice_the_same_way_is_read(tmp_path):
    _raw_mcap(tmp_path / "same.mcap", HEAD + [HEAD[2]] + _samples(), {"driver_id": "D1", "session_id": "s1"})
    res = ingest_one(tmp_path / "same.mcap", tmp_path / "ws")
    assert res.status in ("ingested", "warning") and res.n_presses == 2, (res.reason, res.warnings)


def test_a_press_after_the_last_sample_is_warned_not_dropped_silently(tmp_path):
    _raw_mcap(
        tmp_path / "late.mcap", HEAD + _samples(press_after_ns=500_000_000), {"driver_id": "D1", "session_id": "s1"}
    )
    res = ingest_one(tmp_path / "late.mcap", tmp_path / "ws")
    assert res.status == "warning" and res.n_presses == 2
    assert any("after the last ego sample" in w and "0.5 s" in w for w in res.warnings), res.warnings


@pytest.mark.parametrize(
    "limit, why", [("inf", "not a finite number"), ("-80", "not a road's"), ("1e9", "not a road's")]
)
def test_mcap_metadata_speed_limit_impossible(tmp_path, limit, why):
    _raw_mcap(tmp_path / "l.mcap", HEAD + _samples(), {"driver_id": "D1", "session_id": "s1", "speed_limit_kph": limit})
    res = ingest_one(tmp_path / "l.mcap", tmp_path / "ws")
    assert res.status == "rejected" and why in res.reason, res.reason


@pytest.mark.parametrize(
    "value, why", [('"fast"', "not a number"), ("-80", "not a road's"), ("inf", "finite"), ("true", "not a number")]
)
def test_mapping_default_speed_limit_is_checked_before_any_log(tmp_path, value, why):
    from ingest.mapping import load_mapping
    from laneprint.errors import UserError

    path = tmp_path / "m.toml"
    path.write_text(f"[metadata]\nspeed_limit_kph = {value}\n")
    with pytest.raises(UserError, match=why):
        load_mapping(path)


# --- names and links -----------------------------------------------------------------------------


def test_a_symlink_out_of_the_input_folder_is_refused_with_its_target(tmp_path):
    outside = tmp_path / "private"
    outside.mkdir()
    write_csv(outside / "secret.csv", *make_recording())
    logs = tmp_path / "logs"
    logs.mkdir()
    meta, ego, traffic = make_recording()
    write_csv(logs / "own.csv", dict(meta, session_id="own"), ego, traffic)
    (logs / "link.csv").symlink_to(outside / "secret.csv")
    (logs / "inner.csv").symlink_to(logs / "own.csv")  # a link inside the folder: read (a duplicate)
    before, t0 = _peak_mb(), time.perf_counter()
    report = ingest_paths([logs], Workspace(tmp_path / "ws"))
    assert time.perf_counter() - t0 < MAX_SECONDS and _grown_mb(before) < MAX_GROWTH_MB
    by_name = {Path(f.source).name: f for f in report.files}
    assert by_name["link.csv"].status == "rejected" and "symbolic link out of logs" in by_name["link.csv"].reason
    assert str(outside / "secret.csv") in by_name["link.csv"].reason
    assert {by_name["own.csv"].status, by_name["inner.csv"].status} == {"ingested", "duplicate"}
    # named itself, the linked file is the user's choice and is read
    assert ingest_paths([logs / "link.csv"], Workspace(tmp_path / "ws")).files[0].status == "ingested"


@pytest.mark.parametrize(
    "driver_id", ["![x](http://127.0.0.1:9/img.png)", "[click](javascript:alert(1))", "**bold** <b>x</b>", "`code` $x$"]
)
def test_a_driver_id_in_markdown_is_shown_as_text(driver_id):
    from dashboard.views import md_escape

    shown = md_escape(driver_id)
    assert "](" not in shown and "<b>" not in shown and "**" not in shown.replace("\\*", "")
    assert shown.replace("\\", "") == driver_id.replace("\\", "")


def test_a_backtracking_traffic_pattern_is_refused_before_any_log(tmp_path):
    """A pattern with nested repetition ('(a|aa)+') would hang on a long column name: refused in one
    line when the mapping is read."""
    from ingest.mapping import load_mapping
    from laneprint.errors import UserError

    m = tmp_path / "m.toml"
    m.write_text('[csv.traffic]\npattern = "^(?P<id>(a|aa)+)_(?P<field>x|v|lane)$"\n')
    t0 = time.perf_counter()
    with pytest.raises(UserError, match="nested repetition"):
        load_mapping(m)
    assert time.perf_counter() - t0 < 5


def test_a_pattern_slow_on_one_files_header_refuses_that_file(monkeypatch):
    """Past the probe, the header's matching has a time limit: that file is refused, not hung."""
    from ingest import csv_reader
    from ingest.mapping import Mapping
    from ingest.rawlog import Rejected

    monkeypatch.setattr(csv_reader, "HEADER_MATCH_S", 0.05)
    mapping = Mapping(traffic_pattern=r"^(?P<id>(a|aa)+)_(?P<field>x|v|lane)$")
    t0 = time.perf_counter()
    with pytest.raises(Rejected, match="traffic pattern took over"):
        csv_reader._vehicle_columns(["a" * 60 + "!"], set(), mapping)
    assert time.perf_counter() - t0 < 5


def _mcap_with(tmp_path: Path, encoding: str, datas: list[bytes], schema: tuple[str, str, str] | None = None) -> Path:
    """An MCAP whose ego topic holds `datas` as `encoding` messages (schema: name, encoding, text)."""
    from mcap.writer import Writer

    path = tmp_path / "odd.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema(name=schema[0], encoding=schema[1], data=schema[2].encode()) if schema else 0
        cid = w.register_channel(topic=TOPIC_EGO, message_encoding=encoding, schema_id=sid)
        for i, d in enumerate(datas):
            w.add_message(cid, log_time=i * 20_000_000, data=d, publish_time=i * 20_000_000)
        w.finish()
    return path


def test_json_valid_only_when_messages_are_joined_is_refused():
    """Two objects in one message and an empty one: joined they read as four rows, alone they are not
    JSON; the fast reader leaves them to the message-by-message one, which names the bad message."""
    import pyarrow as pa

    from ingest.mcap_reader import _arrow_table, _decode
    from ingest.rawlog import Rejected

    ok = b'{"x": 0.0, "v": 20.0, "lane": 0}'
    datas = [ok, ok + b" " + ok, b"", ok]
    assert _arrow_table(datas, pa.schema([("x", pa.float64()), ("v", pa.float64())])) is None
    with pytest.raises(Rejected, match="message 1 on /ego/state .* is not valid JSON"):
        _decode(TOPIC_EGO, datas, [0, 1, 2, 3])
    nested = [b'{"vehicles": [{"id": "a", "x": 1.0}, {"id": "b", "x": 2.0}]}'] * 3  # objects in a list: fine
    assert _arrow_table(nested, pa.schema([("vehicles", pa.list_(pa.struct([("x", pa.float64())])))])) is not None


def test_json_declared_cdr_is_refused_not_read_as_numbers(tmp_path):
    from ingest.limits import IngestLimits
    from ingest.mcap_decoding import FastRos2DecoderFactory, decode_topic
    from ingest.mcap_reader import read_mcap_file
    from ingest.rawlog import Rejected

    schema = ("laneprint/msg/Ego", "ros2msg", "float64 x\nfloat64 v\nint32 lane\n")
    path = _mcap_with(tmp_path, "cdr", [b'{"x": 0.0, "v": 20.0, "lane": 0}'] * 3, schema)
    got = read_mcap_file(path.read_bytes(), IngestLimits())
    with pytest.raises(Rejected, match="declared cdr but does not start with a CDR header .it looks like JSON"):
        decode_topic(got, TOPIC_EGO, "log_time", [FastRos2DecoderFactory()], "")


# --- every file of the suite in a fresh process ----------------------------------------------------

#: Handles each [kind, path] of argv[1] (JSON) in turn in this process, its peak RSS (VmHWM) reset before each:
#: 'log' is ingested into a workspace of its own, 'mapping' read. Prints per item what came of it, the
#: seconds and the process's peak resident memory [MB] while it was handled. A plain log goes first,
#: unmeasured, so that the imports a first ingest makes are not counted to a hostile file's time.
MEASURE = """
import json, sys, time
from pathlib import Path
from ingest.mapping import load_mapping
from ingest.pipeline import ingest_paths
from laneprint.errors import UserError
from laneprint.workspace import Workspace

def peak_mb():
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmHWM:"))

items = json.loads(sys.argv[1])
out = []
for k, (kind, path) in enumerate(items):
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # the peak starts again from the current size
    t0 = time.perf_counter()
    try:
        if kind == "mapping":
            load_mapping(Path(path))
            what = "read"
        else:
            res = ingest_paths([Path(path)], Workspace(Path(path).parent / f"ws{k}")).files[0]
            what = f"{res.status}: {res.reason}"
    except UserError as exc:
        what = f"refused: {exc}"
    out.append({"path": Path(path).name, "what": what, "s": round(time.perf_counter() - t0, 3),
                "peak_mb": round(peak_mb(), 1)})
print(json.dumps(out[1:]))
"""


def _suite_files(root: Path) -> list[list[str]]:
    """Every file this suite and tests/ingest/test_hostile_settings_files.py hand to the ingest or the
    mapping reader, written under `root`: [kind, path] each ('log' or 'mapping'); a plain log first."""
    from tests.ingest.test_hostile_settings_files import LAUGHS, test_mappings_of_the_wrong_type_are_one_line

    root.mkdir()
    items: list[list[str]] = []

    def log(name: str, recording: tuple, fmt: str) -> None:
        path = root / f"{name}.{fmt}"
        (write_csv if fmt == "csv" else write_mcap)(path, *recording)
        items.append(["log", str(path)])

    log("warm-up", make_recording(), "csv")
    for i, (change, fmt, _, _) in enumerate(CASES.values()):
        log(f"case{i:02d}", change(*make_recording()), fmt)
    log("plain", make_recording(), "mcap")
    log("collision", _collision(*make_recording()), "csv")
    raw = {
        "twice": HEAD + [("channel", 3, "/other/topic", 0, b"")] + _samples(),
        "same": HEAD + [HEAD[2]] + _samples(),
        "late": HEAD + _samples(press_after_ns=500_000_000),
    }
    for name, records in raw.items():
        _raw_mcap(root / f"{name}.mcap", records, {"driver_id": "D1", "session_id": "s1"})
        items.append(["log", str(root / f"{name}.mcap")])
    for k, limit in enumerate(("inf", "-80", "1e9")):
        _raw_mcap(
            root / f"limit{k}.mcap",
            HEAD + _samples(),
            {"driver_id": "D1", "session_id": "s1", "speed_limit_kph": limit},
        )
        items.append(["log", str(root / f"limit{k}.mcap")])
    links = root / "links"
    links.mkdir()
    (links / "link.csv").symlink_to(root / "case00.csv")
    items.append(["log", str(links)])
    for name, text in (
        ("aliases", "rosbag2_bagfile_information:\n  x: 1\n" + LAUGHS),
        (
            "listed-twice",
            "rosbag2_bagfile_information:\n  storage_identifier: mcap\n"
            "  relative_file_paths:\n" + "    - bag_0.mcap\n" * 100,
        ),
    ):
        (root / name).mkdir()
        (root / name / "metadata.yaml").write_text(text)
        items.append(["log", str(root / name)])
    (root / "bomb.yaml").write_text(LAUGHS)
    (root / "big.toml").write_text("# " + "x" * (1024 * 1024 + 10))
    (root / "bin.toml").write_bytes(b"\xff\xfe\x00garbage")
    items += [["mapping", str(root / n)] for n in ("bomb.yaml", "big.toml", "bin.toml")]
    wrong = test_mappings_of_the_wrong_type_are_one_line.pytestmark[0].args[1]  # its parametrized (text, why)
    for k, (text, _) in enumerate(wrong):
        (root / f"wrong{k}.toml").write_text(text)
        items.append(["mapping", str(root / f"wrong{k}.toml")])
    return items


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="per-file peak RSS needs Linux's clear_refs")
def test_each_file_of_the_suite_takes_under_5_s_and_600_mb_in_a_fresh_process(tmp_path):
    """The suite's acceptance measured where nothing else counts: one process that handles the hostile files
    one by one, its peak resident memory reset before each (absolute, not the growth: imports included)."""
    import subprocess
    import sys

    items = _suite_files(tmp_path / "files")
    proc = subprocess.run(
        [sys.executable, "-c", MEASURE, json.dumps(items)], capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.splitlines()[-1])
    assert len(out) == len(items) - 1 >= 35
    for r in out:
        assert "Traceback" not in r["what"] and "please report" not in r["what"], r
        assert r["s"] < MAX_SECONDS and r["peak_mb"] < MAX_GROWTH_MB, r
