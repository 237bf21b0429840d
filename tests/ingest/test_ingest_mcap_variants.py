"""Every valid MCAP is read, whatever its writer left out: the mcap writer's options, and the
MCAP project's 416 conformance files (regenerated offline, `data/mcap_conformance.tar.gz`)."""

from __future__ import annotations

import io
import json
import tarfile
from pathlib import Path

import pandas as pd
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer
from typer.testing import CliRunner

import ingest.mcap_records as mcap_records
from ingest.mcap_records import read_records, read_stream, top_records
from ingest.pipeline import ingest_paths
from ingest.writers import write_mcap
from laneprint.app.cli import app
from laneprint.workspace import Workspace

CONFORMANCE = Path(__file__).parent / "data" / "mcap_conformance.tar.gz"
NO_SUMMARY = dict(
    repeat_channels=False,
    repeat_schemas=False,
    use_statistics=False,
    index_types=IndexType.NONE,
    use_summary_offsets=False,
)
VARIANTS: dict[str, dict] = {
    "default": {},
    "no_repeat_channels": dict(repeat_channels=False),
    "no_repeat_schemas": dict(repeat_schemas=False),
    "no_repeats": dict(repeat_channels=False, repeat_schemas=False),
    "no_chunk_index": dict(index_types=IndexType.MESSAGE | IndexType.METADATA),
    "no_index": dict(index_types=IndexType.NONE),
    "no_statistics": dict(use_statistics=False),
    "no_summary": NO_SUMMARY,
    "unchunked": dict(use_chunking=False),
    "uncompressed": dict(compression=CompressionType.NONE),
    "lz4": dict(compression=CompressionType.LZ4),
    "small_chunks_lz4_no_repeats": dict(chunk_size=1024, compression=CompressionType.LZ4, repeat_channels=False),
    "large_chunks": dict(chunk_size=64 << 20),
    "small_chunks_no_summary": dict(chunk_size=512, **NO_SUMMARY),
}


def rewrite(src: bytes, session_id: str, **options) -> bytes:
    """The messages and metadata of `src`, written again by mcap's `Writer` with `options`."""
    reader = make_reader(io.BytesIO(src))
    out = io.BytesIO()
    w = Writer(out, **options)
    w.start(profile="", library="variant")
    ids: dict[int, int] = {}
    for md in reader.iter_metadata():
        w.add_metadata(md.name, dict(md.metadata, session_id=session_id) if md.name == "session" else md.metadata)
    for schema, channel, msg in reader.iter_messages(log_time_order=False):
        if channel.id not in ids:
            sid = w.register_schema(schema.name, schema.encoding, schema.data)
            ids[channel.id] = w.register_channel(channel.topic, channel.message_encoding, sid, channel.metadata)
        w.add_message(ids[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
    w.finish()
    return out.getvalue()


@pytest.fixture(scope="module")
def variants(tmp_path_factory, module_recording) -> Path:
    """A folder with the recording written under every option of `VARIANTS` (session id = variant)."""
    folder = tmp_path_factory.mktemp("variants")
    meta, ego, traffic = module_recording
    write_mcap(folder / "src.mcap.tmp", meta, ego, traffic)
    src = (folder / "src.mcap.tmp").read_bytes()
    (folder / "src.mcap.tmp").unlink()
    for name, options in VARIANTS.items():
        (folder / f"{name}.mcap").write_bytes(rewrite(src, name, **options))
    return folder


def test_the_variants_lack_what_they_say(variants):
    summary = make_reader(io.BytesIO((variants / "no_repeats.mcap").read_bytes())).get_summary()
    assert summary.chunk_indexes and not summary.channels and not summary.schemas
    assert not make_reader(io.BytesIO((variants / "no_chunk_index.mcap").read_bytes())).get_summary().chunk_indexes
    assert make_reader(io.BytesIO((variants / "no_summary.mcap").read_bytes())).get_summary() is None


def test_cli_reads_every_variant_to_the_same_tables(variants, tmp_path):
    ws = tmp_path / "ws"
    out = CliRunner().invoke(app, ["ingest", str(variants), "-w", str(ws), "--json"])
    assert out.exit_code == 0, out.output
    files = {Path(f["source"]).stem: f for f in json.loads(out.stdout)["files"]}
    assert {k: (f["status"], f["reason"]) for k, f in files.items()} == {k: ("ingested", "") for k in VARIANTS}
    workspace = Workspace(ws)
    _, ego0, traffic0 = workspace.load_recording(files["default"]["recording_id"])
    assert (len(ego0), len(traffic0), files["default"]["n_presses"]) == (200, 325, 2)
    for name, f in files.items():
        _, ego, traffic = workspace.load_recording(f["recording_id"])
        pd.testing.assert_frame_equal(ego, ego0, obj=f"{name} ego")
        pd.testing.assert_frame_equal(traffic, traffic0, obj=f"{name} traffic")


def _messages(got) -> list[tuple[str, int, bytes]]:
    return sorted((got.channels[c].topic, t, d) for c in got.times for t, d in zip(got.times[c], got.datas[c]))


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_fast_walk_reads_what_the_mcap_stream_reader_reads(variants, name):
    data = (variants / f"{name}.mcap").read_bytes()
    fast, slow = read_records(data), read_stream(data)
    assert _messages(fast) == _messages(slow) and len(_messages(fast)) == 200 * 3 + 4 + 1
    assert fast.metadata == slow.metadata and fast.metadata["session"]["session_id"] == name


def _walked_only(data: bytes, monkeypatch):
    with monkeypatch.context() as m:
        m.setattr(mcap_records, "_walk_indexed", lambda *args: False)
        return read_records(data)


@pytest.mark.parametrize("name", ["default", "small_chunks_lz4_no_repeats", "no_repeats"])
def test_chunks_cut_at_their_message_index_read_as_the_walk_does(variants, name, monkeypatch):
    """The numpy cut by Message Index offsets gives the walk's messages in the walk's order."""
    data = (variants / f"{name}.mcap").read_bytes()
    used = []
    real = mcap_records._walk_indexed
    monkeypatch.setattr(mcap_records, "_walk_indexed", lambda *a: used.append(real(*a)) or used[-1])
    fast = read_records(data)
    assert used and all(used)
    walked = _walked_only(data, monkeypatch)
    assert (fast.times, fast.datas, fast.channels.keys()) == (walked.times, walked.datas, walked.channels.keys())


def test_a_message_index_that_lies_sends_its_chunk_to_the_walk(variants, monkeypatch):
    data = bytearray((variants / "default.mcap").read_bytes())
    op, pos, length = next(h for h in top_records(bytes(data)) if h[0] == 0x07 and h[2] > 6 + 16)
    data[pos + 9 + 6 + 8 : pos + 9 + 6 + 16] = (7).to_bytes(8, "little")  # its first offset, into a record
    used = []
    real = mcap_records._walk_indexed
    monkeypatch.setattr(mcap_records, "_walk_indexed", lambda *a: used.append(real(*a)) or used[-1])
    got = read_records(bytes(data))
    assert False in used
    walked = _walked_only(bytes(data), monkeypatch)
    assert (got.times, got.datas) == (walked.times, walked.datas) and sum(map(len, got.times.values())) == 605


def test_a_message_index_that_does_not_fit_its_record_is_skipped_not_fatal(variants, monkeypatch):
    data = bytearray((variants / "default.mcap").read_bytes())
    op, pos, length = next(h for h in top_records(bytes(data)) if h[0] == 0x07 and h[2] > 6 + 16)
    data[pos + 9 + 2 : pos + 9 + 6] = (length + 16).to_bytes(4, "little")  # entries past the record's end
    got = read_records(bytes(data))  # the chunk is walked instead: no refusal, nothing lost
    assert (got.times, got.datas) == (lambda w: (w.times, w.datas))(_walked_only(bytes(data), monkeypatch))
    assert sum(map(len, got.times.values())) == 605


def test_messages_on_a_channel_no_record_defines_are_refused_naming_the_id(tmp_path):
    out = io.BytesIO()
    w = Writer(out, use_chunking=False, **{k: v for k, v in NO_SUMMARY.items()})
    w.start()
    cid = w.register_channel("/ego/state", "json", 0)
    for i in range(3):
        w.add_message(cid, i, b"{}", i)
    w.finish()
    data = out.getvalue()
    at = data.index(b"\x04", 8 + 9 + 8)  # the Channel record after the Header
    (length,) = __import__("struct").unpack_from("<Q", data, at + 1)
    path = tmp_path / "orphans.mcap"
    path.write_bytes(data[:at] + data[at + 9 + length :])
    (res,) = ingest_paths([path], Workspace(tmp_path / "ws")).files
    assert res.status == "rejected"
    assert res.reason == "corrupt MCAP: 3 message(s) on channel id(s) 1, which no Channel record in the file defines"


@pytest.fixture(scope="module")
def conformance(tmp_path_factory) -> Path:
    if not CONFORMANCE.exists():
        pytest.skip(f"{CONFORMANCE} is absent (see /work/shared/recipes/MCAP_CONFORMANCE.md to regenerate it)")
    folder = tmp_path_factory.mktemp("conformance")
    with tarfile.open(CONFORMANCE) as tar:
        tar.extractall(folder, filter="data")
    return folder


# messages and Metadata records each conformance input holds (the generator's inputs)
CONFORMANCE_CONTENT = {
    "NoData": (0, 0),
    "OneAttachment": (0, 0),
    "OneMetadata": (0, 1),
    "OneMessage": (1, 0),
    "OneSchemalessMessage": (1, 0),
    "TenMessages": (10, 0),
}


def test_every_conformance_file_is_read_by_the_fast_walk(conformance):
    files = sorted(conformance.rglob("*.mcap"))
    assert len(files) == 416
    for path in files:
        got = read_records(path.read_bytes())  # raises on anything it does not understand
        n_msgs, n_meta = CONFORMANCE_CONTENT[path.parent.name]
        assert (len(_messages(got)), len(got.metadata)) == (n_msgs, n_meta), path.name
        assert {ch.topic for ch in got.channels.values()} == ({"example"} if n_msgs else set()), path.name
        if path.parent.name == "TenMessages":
            assert _messages(got) == _messages(read_stream(path.read_bytes())), path.name


def test_cli_refuses_conformance_files_for_their_topics_not_as_corrupt(conformance, tmp_path):
    """They hold no laneprint topics: the reason names the missing topic (112 were 'corrupt' before)."""
    out = CliRunner().invoke(app, ["ingest", str(conformance / "TenMessages"), "-w", str(tmp_path / "ws"), "--json"])
    assert out.exit_code == 0, out.output
    reasons = [f["reason"] for f in json.loads(out.stdout)["files"]]
    assert len(reasons) == 154
    assert all(
        r.startswith("missing required topic /ego/state") and "topics in the file: example" in r for r in reasons
    ), {r for r in reasons if not r.startswith("missing")}
