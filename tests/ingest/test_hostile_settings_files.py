"""Settings files that arrive with the data, small files meant to grow: refused in one line, fast."""

from __future__ import annotations

import re
import time

import pytest

from ingest.mapping import load_mapping
from ingest.rosbag2 import read_bag_info
from ingest.rawlog import Rejected
from laneprint.errors import UserError

LAUGHS = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{chr(98 + i)}: &{chr(98 + i)} [*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, "
    f"*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}]\n"
    for i in range(9)
)


def test_yaml_mapping_with_nested_aliases_is_refused_at_once(tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(LAUGHS)
    t0 = time.perf_counter()
    with pytest.raises(UserError, match="aliases"):
        load_mapping(path)
    assert time.perf_counter() - t0 < 2


def test_bag_metadata_with_aliases_is_refused(tmp_path):
    (tmp_path / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  x: 1\n" + LAUGHS)
    with pytest.raises(Rejected, match="aliases"):
        read_bag_info(tmp_path)


def test_bag_part_listed_twice_is_refused(tmp_path):
    (tmp_path / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  storage_identifier: mcap\n  relative_file_paths:\n"
        + "    - bag_0.mcap\n" * 100
    )
    with pytest.raises(Rejected, match="more than once"):
        read_bag_info(tmp_path)


def test_huge_or_binary_mapping_is_refused(tmp_path):
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * (1024 * 1024 + 10))
    with pytest.raises(UserError, match="larger than"):
        load_mapping(big)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(UserError, match="UTF-8"):
        load_mapping(binary)


def test_driver_ids_are_one_form_bounded_and_printable():
    from ingest.validate import clean_id, resolve_driver

    composed, decomposed = "Jos\u00e9", "Jose\u0301"
    assert resolve_driver(composed, None, None, []) == resolve_driver(decomposed, None, None, [])
    with pytest.raises(Rejected, match="at most"):
        resolve_driver("x" * 300, None, None, [])
    with pytest.raises(Rejected, match="control characters"):
        clean_id("D01\x1b[2J")
    with pytest.raises(Rejected, match="at most"):
        resolve_driver(None, None, "y" * 65, [])


@pytest.mark.parametrize(
    "text, why",
    [
        ("csv = 5\n", "[csv] must be a table"),
        ("csv = [1, 2]\n", "[csv] must be a table"),
        ("units = [1]\n", "[units] must be a table"),
        ('[csv]\ntraffic = "x"\n', "[csv.traffic] must be a table"),
        ("[units]\nspeed_scale = nan\n", "positive finite number"),
        ("[units]\nspeed_scale = inf\n", "positive finite number"),
        ("[units]\nspeed_scale = true\n", "positive finite number"),
    ],
)
def test_mappings_of_the_wrong_type_are_one_line(tmp_path, text, why):
    path = tmp_path / "m.toml"
    path.write_text(text)
    with pytest.raises(UserError, match=re.escape(why)):
        load_mapping(path)
