import io

import pytest

from dashboard.uploads import has_log_suffix, safe_filename, save_upload


@pytest.mark.parametrize("name, expected", [
    ("rec.csv", "rec.csv"),
    ("../../x.csv", "x.csv"),
    ("..\\..\\evil.mcap", "evil.mcap"),
    ("/etc/passwd", "passwd"),
    (".hidden.csv", "hidden.csv"),
    ("a b;rm -rf.csv.gz", "a_b_rm_-rf.csv.gz"),
    ("", "upload"),
    ("..", "upload"),
    ("../", "upload"),
])
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
        True, True, True, False, False]


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
