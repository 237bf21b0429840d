"""`first_line`: the one-line reason quoted in errors and warnings."""

from ingest.rawlog import first_line


def test_first_line_of_a_blank_text_quotes_it_and_of_a_bare_exception_names_its_type():
    assert first_line("  ") == "'  '"
    assert first_line(ValueError()) == "ValueError"
    assert first_line("bad value\nmore") == "bad value"
    assert first_line("x" * 300).endswith("...")
