"""The GitHub Actions workflow the harness guide documents is complete and consistent:
a trigger, a job that builds the decoder, installs fbaconf, runs it with the paths the
guide names, and uploads the report and the JUnit file — and the guide shows this file."""

from __future__ import annotations

import shlex
from pathlib import Path

import yaml

DOCS = Path(__file__).resolve().parents[2] / "docs"
WORKFLOW = DOCS / "examples" / "github-actions.yml"


def test_workflow_is_complete():
    wf = yaml.safe_load(WORKFLOW.read_text("utf-8"))
    assert wf.get(True) or wf.get("on"), "no trigger (on:)"  # YAML 1.1 reads a bare `on` as True
    (job,) = wf["jobs"].values()
    steps = job["steps"]
    runs = [s["run"] for s in steps if "run" in s]
    fb = next(r for r in runs if "fbaconf run" in r)
    argv = shlex.split(fb)
    out = argv[argv.index("-o") + 1]
    junit = argv[argv.index("--junit") + 1]
    assert junit.startswith(out + "/"), "the JUnit file is written into the uploaded folder"
    assert "--baseline" in argv and "--decoder" in argv
    uploads = [s for s in steps if str(s.get("uses", "")).startswith("actions/upload-artifact")]
    assert uploads and uploads[0]["with"]["path"] == out and uploads[0].get("if") == "always()"
    junit_steps = [s for s in steps if "junit" in str(s.get("uses", "")).lower()]
    assert junit_steps and junit_steps[0]["with"]["report_paths"] == junit
    assert any("pip install" in r for r in runs) and runs.index(
        next(r for r in runs if "pip install" in r)
    ) < runs.index(fb)


def test_guide_shows_the_checked_workflow():
    guide = (DOCS / "harness.md").read_text("utf-8")
    assert WORKFLOW.read_text("utf-8") in guide
