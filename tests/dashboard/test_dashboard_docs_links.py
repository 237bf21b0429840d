"""The dashboard's help links to the documentation site: shown once a site is built, never dead; served by
Streamlit's static route (the page and anchor checks against a built site are in tests/docs)."""

import sys

import pytest

from dashboard import docs_site
from dashboard.cli import streamlit_command


def test_links_appear_only_once_the_site_is_built(tmp_path, monkeypatch):
    monkeypatch.setattr(docs_site, "SITE", tmp_path / "docs")
    assert docs_site.more("styles") == "" and docs_site.with_more("Help.", "styles") == "Help."
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "index.html").write_text("<html></html>")
    assert docs_site.more("styles") == "More: [How laneprint reads styles](app/static/docs/concepts/styles.html)"
    assert docs_site.with_more("Help.", "ray") == "Help.\n\nMore: [Ray clusters](app/static/docs/howto/ray.html)"
    with pytest.raises(KeyError, match="LINKS"):
        docs_site.more("no such page")


def test_the_site_is_rebuilt_when_a_source_is_newer(tmp_path):
    root, site = tmp_path / "repo", tmp_path / "site"
    assert docs_site.sources(root) == [] and not docs_site.stale(site, root)  # an install without the sources
    (root / "docs").mkdir(parents=True)
    (root / "mkdocs.yml").write_text("site_name: x\n")
    (root / "docs" / "index.md").write_text("# x\n")
    assert docs_site.stale(site, root)  # not built yet
    site.mkdir()
    (site / "index.html").write_text("")
    import os

    os.utime(site / "index.html", (1e9, 1e9))
    assert docs_site.stale(site, root)
    os.utime(site / "index.html", None)
    os.utime(root / "docs" / "index.md", (1e9, 1e9))
    os.utime(root / "mkdocs.yml", (1e9, 1e9))
    assert not docs_site.stale(site, root)


def test_the_server_serves_the_static_folder_next_to_the_app(tmp_path):
    cmd = streamlit_command(8999, "127.0.0.1", tmp_path)
    assert cmd[:4] == [sys.executable, "-m", "streamlit", "run"]
    args = cmd[5 : cmd.index("--")]
    assert dict(zip(args[::2], args[1::2]))["--server.enableStaticServing"] == "true"
    assert docs_site.STATIC.parent / "app.py" == docs_site.Path(cmd[4])  # Streamlit's static/ is next to the script
