"""The documentation site, served offline by the dashboard, and the help links to its pages.

The site (MkDocs, `mkdocs.yml` and `docs/` of a checkout) is built with ``--no-directory-urls`` into
`dashboard/static/docs/`, which Streamlit serves as static files at ``app/static/docs/`` (the
launcher turns on ``server.enableStaticServing``; Streamlit serves `.html` as ``text/html``). So
each page is one file, ``concepts/styles.html``, reachable without a web server of its own.

- `laneprint dashboard` builds it in the background when the sources are there (a checkout or an
  editable install with the docs extra) and the built copy is missing or older than them
  (`ensure_site`); `python -m dashboard.docs_site` builds it by hand, for example before building a
  wheel, which then ships it as package data.
- `more(key)` is a help text's "More: [title](link)" to the page of `LINKS`, or "" while no site is
  built (no dead links); the tests check that every link's page and anchor exist in the built site.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

#: Where the built site lives: the `static/` folder Streamlit serves next to `dashboard/app.py`.
STATIC = Path(__file__).with_name("static")
SITE = STATIC / "docs"
#: The site's address relative to a dashboard page (Streamlit's static route).
URL = "app/static/docs"
#: The checkout the site is built from, when this package sits in one.
ROOT = Path(__file__).resolve().parents[1]

#: Help link -> (page of the site without `.md`, with an optional `#anchor`; the link's text).
LINKS: dict[str, tuple[str, str]] = {
    "data": ("your-own-study", "Your own study"),
    "indicators": ("concepts/indicators", "The indicators"),
    "directions": ("concepts/indicators#lines-against-ego-speed", "Lines against ego speed"),
    "used_values": ("concepts/indicators#which-values-the-statistics-use", "Which values the statistics use"),
    "styles": ("concepts/styles", "How laneprint reads styles"),
    "readings": ("concepts/styles#choosing-a-reading-by-what-styles-are-for", "Readings of the styles"),
    "behaviour": ("concepts/styles#behaviour-parameters-what-a-driver-needs-before-it-goes", "Behaviour parameters"),
    "confidence": ("concepts/styles#confidence-and-why-a-driver-is-unsure", "Confidence"),
    "formulations": ("concepts/formulations", "Formulations of the decision"),
    "agents": ("concepts/agents", "Agents and learners"),
    "learners": ("concepts/agents#the-learners", "The learners"),
    "heldout": ("concepts/agents#held-out-by-session", "Held out by session"),
    "scoring": ("concepts/agents#how-an-agent-is-scored", "How an agent is scored"),
    "personal": ("concepts/agents#fleets-and-personal-agents", "Fleets and personal agents"),
    "closed_loop": ("concepts/closed-loop", "Closed-loop driving"),
    "ray": ("howto/ray", "Ray clusters"),
    "onnx": ("howto/onnx", "ONNX into a vehicle stack"),
    "report": ("howto/report", "The report"),
}


def target(key: str) -> tuple[str, str]:
    """(file of the built site, anchor) of a help link: ('concepts/styles.html', 'confidence-...')."""
    page, _, anchor = LINKS[key][0].partition("#")
    return f"{page}.html", anchor


def url(key: str) -> str:
    """The link's address relative to a dashboard page."""
    file, anchor = target(key)
    return f"{URL}/{file}" + (f"#{anchor}" if anchor else "")


def built(site: Path | None = None) -> bool:
    """Whether a built site is there to link to (by default `SITE`)."""
    return ((site or SITE) / "index.html").is_file()


def more(key: str) -> str:
    """ "More: [title](link)" for a help text or caption; "" while no site is built."""
    if key not in LINKS:
        raise KeyError(f"no help link {key!r}: add it to dashboard.docs_site.LINKS")
    return f"More: [{LINKS[key][1]}]({url(key)})" if built() else ""


def with_more(text: str, key: str) -> str:
    """`text` and, when the site is built, its "More:" link on a line of its own."""
    link = more(key)
    return f"{text}\n\n{link}" if link else text


def sources(root: Path | None = None) -> list[Path]:
    """The files the site is built from (mkdocs.yml and docs/), or [] outside a checkout."""
    root = root or ROOT
    if not (root / "mkdocs.yml").is_file() or not (root / "docs").is_dir():
        return []
    return [root / "mkdocs.yml", *(p for p in (root / "docs").rglob("*") if p.is_file())]


def stale(site: Path | None = None, root: Path | None = None) -> bool:
    """Whether the sources are there and the built site is missing or older than one of them."""
    site = site or SITE
    files = sources(root)
    if not files:
        return False
    if not built(site):
        return True
    return max(p.stat().st_mtime for p in files) > (site / "index.html").stat().st_mtime


def build(site: Path | None = None, root: Path | None = None, timeout_s: float = 300.0) -> str | None:
    """Build the site from `root` into `site` (written aside, then swapped in); None, or why it was not."""
    site, root = site or SITE, root or ROOT
    if not sources(root):
        return f"no documentation sources at {root} (mkdocs.yml and docs/)"
    if importlib.util.find_spec("mkdocs") is None:
        return "mkdocs is not installed: pip install -e '.[docs]'"
    site.parent.mkdir(parents=True, exist_ok=True)
    tmp = site.with_name(f".{site.name}.tmp-{uuid.uuid4().hex[:8]}")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    try:
        res = subprocess.run(
            [sys.executable, "-m", "mkdocs", "build", "-q", "--no-directory-urls", "-d", str(tmp)],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            env=env,
        )
        if res.returncode or not built(tmp):
            return f"mkdocs build failed: {(res.stderr or res.stdout).strip()[-500:]}"
        old = site.with_name(f".{site.name}.old-{uuid.uuid4().hex[:8]}")
        if site.exists():
            os.rename(site, old)
        os.rename(tmp, site)
        shutil.rmtree(old, ignore_errors=True)
        return None
    except (OSError, subprocess.SubprocessError) as exc:
        return f"mkdocs build failed: {exc}"
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def ensure_site() -> str | None:
    """Build the site when the sources are there and it is missing or stale; None, or why not built."""
    return build() if stale() else None


if __name__ == "__main__":
    why = build()
    print(why or f"documentation site built in {SITE}")
    sys.exit(1 if why else 0)
