import io

import pytest

from dashboard.uploads import has_log_suffix, safe_filename, save_upload


@pytest.mark.parametrize(
    "name, expected",
    [
        ("rec.csv", "rec.csv"),
        ("../../x.csv", "x.csv"),
        ("..\\..\\evil.mcap", "evil.mcap"),
        ("/etc/passwd", "passwd"),
        (".hidden.csv", "hidden.csv"),
        ("a b;rm -rf.csv.gz", "a_b_rm_-rf.csv.gz"),
        ("", "upload"),
        ("..", "upload"),
        ("../", "upload"),
    ],
)
def test_safe_filename(name, expected):
    assert safe_filename(name) == expected


def test_names_in_other_scripts_stay_apart_and_a_bare_suffix_stays_a_log():
    names = ["Сессия_01.csv", "Поездка_01.csv", "运行_01.csv", "جلسة_01.csv"]
    saved = [safe_filename(n) for n in names]
    assert saved == names and len(set(saved)) == 4
    assert safe_filename("Jose\u0301.csv") == "Jos\u00e9.csv"  # one form
    assert safe_filename("a\u202ecod.exe.csv") == "a_cod.exe.csv"  # a bidi override is not kept
    assert safe_filename(".csv") == "upload.csv" and safe_filename(".MCAP") == "upload.MCAP"
    assert has_log_suffix(safe_filename(".csv.gz"))


def test_has_log_suffix():
    assert [has_log_suffix(n) for n in ("a.CSV", "a.csv.gz", "b.mcap", "c.txt", "d.gz")] == [
        True,
        True,
        True,
        False,
        False,
    ]


def test_traversal_name_stays_inside(tmp_path):
    updir = tmp_path / "ws" / "uploads"
    s = save_upload("../../../x.csv", 3, io.BytesIO(b"a,b"), updir, 1000)
    assert s.path is not None and s.path.is_relative_to(updir.resolve())
    assert s.path.name == "x.csv" and s.path.read_bytes() == b"a,b"
    assert not (tmp_path / "x.csv").exists()
    assert sorted(p.name for p in tmp_path.rglob("x.csv")) == ["x.csv"]


def test_same_bytes_same_place_and_refusals(tmp_path):
    a = save_upload("r.csv", 3, io.BytesIO(b"abc"), tmp_path, 1000)
    b = save_upload("r.csv", 3, io.BytesIO(b"abc"), tmp_path, 1000)
    c = save_upload("r.csv", 3, io.BytesIO(b"abd"), tmp_path, 1000)
    assert a.path == b.path != c.path
    assert save_upload("e.csv", 0, io.BytesIO(b""), tmp_path, 1000).reason.startswith("empty file")
    big = save_upload("big.mcap", 2000, io.BytesIO(b"x" * 2000), tmp_path, 1000)
    assert big.path is None and "laneprint ingest" in big.reason
    txt = save_upload("notes.txt", 3, io.BytesIO(b"abc"), tmp_path, 1000)
    assert txt.path is None and txt.reason.startswith("not a log")
    assert not list((tmp_path / ".partial").iterdir())


def test_discard_only_inside_uploads(tmp_path):
    from dashboard.uploads import discard

    s = save_upload("r.csv", 3, io.BytesIO(b"abc"), tmp_path / "uploads", 1000)
    outside = tmp_path / "keep.csv"
    outside.write_text("x")
    discard(outside, tmp_path / "uploads")
    assert outside.exists()
    discard(s.path, tmp_path / "uploads")
    assert not s.path.exists() and not s.path.parent.exists()


def test_upload_larger_than_declared_is_cut_off_and_refused(tmp_path):
    class Counting(io.BytesIO):
        biggest_read = 0

        def read(self, n=-1):
            Counting.biggest_read = max(Counting.biggest_read, n)
            return super().read(n)

    lying = save_upload("lie.csv", 10, Counting(b"x" * (5 << 20)), tmp_path, 3 << 20)
    assert lying.path is None and lying.reason.startswith("too large for the browser upload (more than 3 MB)")
    assert not list((tmp_path / ".partial").iterdir())
    assert 0 < Counting.biggest_read <= 1 << 20  # copied in chunks, never read whole


#: In a fresh process: a 300 MB upload as the Data page gets it (Streamlit's `UploadedFile`, a BytesIO over
#: the received bytes) saved by `save_upload`, then 300 MB from a stream that never holds them (a browser that
#: declared 1 KB) against a 100 MB limit. Prints the peak and current RSS [MB] before and after each.
UPLOAD_RSS = """
import io, json, resource, sys
from pathlib import Path
from streamlit.runtime.uploaded_file_manager import UploadedFile, UploadedFileRec
from dashboard.uploads import save_upload

MB = 1 << 20
peak = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # noqa: E731 (KB on Linux)
rss = lambda: int(open("/proc/self/statm").read().split()[1]) * resource.getpagesize() / MB  # noqa: E731


class Endless(io.RawIOBase):  # `size` bytes made as they are read
    def __init__(self, size):
        self.left = size

    def readable(self):
        return True

    def readinto(self, b):
        n = min(len(b), self.left)
        b[:n] = bytes(n)
        self.left -= n
        return n


out = {}
updir = Path(sys.argv[1])
data = b"0123456789abcdef" * (300 * MB // 16)
f = UploadedFile(UploadedFileRec("id", "big.csv", "text/csv", data), None)
del data
before = (peak(), rss())
s = save_upload(f.name, f.size, f, updir, 1024 * MB)
out["whole"] = {"saved": s.path is not None and s.path.stat().st_size, "peak": [before[0], peak()],
                "rss": [before[1], rss()]}
s.path.unlink()
del f
before = (peak(), rss())
s = save_upload("lie.mcap", 1024, io.BufferedReader(Endless(300 * MB)), updir, 100 * MB)
out["lying"] = {"reason": s.reason, "written": s.size, "peak": [before[0], peak()], "rss": [before[1], rss()]}
print(json.dumps(out))
"""


@pytest.mark.slow
def test_a_300_mb_upload_is_saved_in_chunks_without_another_copy_in_memory(tmp_path):
    """The issue's 300 MB upload: `save_upload`, which the Data page calls, adds a few MB to the process's
    peak (the bytes Streamlit received are not copied again), and a stream over the limit is cut off at
    the limit whatever size was declared, without holding what it read."""
    import json
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-c", UPLOAD_RSS, str(tmp_path / "uploads")], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.splitlines()[-1])
    whole, lying = out["whole"], out["lying"]
    assert whole["saved"] == 300 << 20
    assert whole["peak"][0] > 300  # the received bytes themselves, as Streamlit holds them
    assert whole["peak"][1] - whole["peak"][0] < 32, whole  # saving them: chunks of 1 MB, no copy of the file
    assert whole["rss"][1] - whole["rss"][0] < 32, whole  # and nothing held afterwards
    assert lying["reason"].startswith("too large for the browser upload (more than 100 MB)")
    assert 100 << 20 < lying["written"] <= (100 << 20) + (1 << 20)  # cut off at the limit
    assert lying["peak"][1] - lying["peak"][0] < 32, lying
    assert not list((tmp_path / "uploads" / ".partial").iterdir())
