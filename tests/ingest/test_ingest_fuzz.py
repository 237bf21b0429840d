"""Property: any damaged copy of a sample log is either ingested whole and valid, or refused with a
reason naming a signal or a byte offset; never a traceback, never a partial recording.

A few dozen derandomized examples here; `python benchmarks/fuzz.py` runs tens of thousands.
"""

from __future__ import annotations

import random
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.support.ingest_mutations import excerpts, kinds_for, mutate, try_ingest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def seeds() -> dict[str, bytes]:
    return excerpts(ROOT / "sample_logs", seconds=(2.0,), n_logs=1)


def _fmt(name: str) -> str:
    return "mcap" if name.endswith(".mcap") else "csv.gz" if name.endswith(".gz") else "csv"


@pytest.mark.slow
@settings(
    max_examples=40,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_a_mutated_log_is_ingested_whole_or_refused_with_a_located_reason(seeds, tmp_path, data):
    name = data.draw(st.sampled_from(sorted(seeds)), label="seed file")
    kind = data.draw(st.sampled_from(kinds_for(_fmt(name))), label="mutation")
    rng = random.Random(data.draw(st.integers(0, 2**32 - 1), label="rng seed"))
    case = tmp_path / f"case-{rng.random()}"
    case.mkdir()
    try:
        (case / name).write_bytes(mutate(seeds[name], _fmt(name), kind, rng))
        out = try_ingest(case / name, case / "ws")
    finally:
        shutil.rmtree(case, ignore_errors=True)
    assert out.outcome in ("ingested", "refused"), f"{kind} of {name}: {out.outcome}\n{out.detail}"


def test_every_mutation_kind_changes_the_file(seeds):
    for name, data in seeds.items():
        for kind in kinds_for(_fmt(name)):
            changed = any(mutate(data, _fmt(name), kind, random.Random(s)) != data for s in range(5))
            assert changed, f"{kind} left {name} unchanged"
