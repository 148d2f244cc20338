"""The documentation site builds with no warning (`mkdocs build --strict`, mkdocs.yml): a broken
link or anchor, a link out of docs/, a page missing from the nav or a docstring mkdocstrings
cannot read fails the build. mkdocstrings reads the API by static analysis (griffe), so the
build imports nothing of volmc and takes a few seconds."""

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_site_builds_strictly(tmp_path):
    site = tmp_path / "site"
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
         str(ROOT / "mkdocs.yml"), "--site-dir", str(site)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for page in ("index.html", "getting_started/index.html", "scene_format/index.html",
                 "which_estimator/index.html", "api/volmc/index.html"):
        assert (site / page).is_file(), page
    api = (site / "api" / "volmc" / "index.html").read_text()
    for name in ("load_scene", "scene_from_dict", "render", "render_frames",
                 "estimate_transmittance", "RenderedImage", "TransmittanceResult"):
        assert f'id="volmc.api.{name}"' in api, name


def test_readme_links_exist():
    """The README's relative links (into docs/) point at files that exist: GitHub shows them,
    and the site build does not read the README."""
    text = (ROOT / "README.md").read_text()
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    local = [link.split("#")[0] for link in links if not re.match(r"[a-z]+:", link)]
    assert local, "the README links into docs/"
    missing = [link for link in local if link and not (ROOT / link).exists()]
    assert not missing, missing
