"""Reports of a harness run, all built from one :class:`~fbaconf.harness.results.RunRecord`,
one module per format:

- :mod:`.terminal` — :func:`terminal_summary`: aligned text tables (per suite, per profile,
  per outcome), the failing cases with what differs, speed results and a verdict line;
- :mod:`.jsonreport` — :func:`write_json` / :func:`read_json`: the record as strict JSON
  (schema ``harness/data/run-report.schema.json``);
- :mod:`.junit` — :func:`write_junit`: JUnit XML for CI systems;
- :mod:`.html` — :func:`write_html`: one self-contained page (CSS from
  ``harness/data/report.css``, inline SVG, no script);
- :mod:`.common` — what they share.

Everything a decoder produced (messages, stderr tails, first-difference values, even
case ids and artefact names) is untrusted: it is escaped for HTML and XML, stripped of
terminal control sequences for the terminal, and characters XML cannot hold are shown
as ``\\xNN`` escapes. Every file is written atomically.
"""

from .common import clean_text, format_difference, profile_of, verdict
from .html import html_report, svg_plot, write_html
from .jsonreport import read_json, report_json, write_json
from .junit import junit_xml, write_junit
from .terminal import terminal_summary

__all__ = [
    "terminal_summary",
    "write_json",
    "read_json",
    "report_json",
    "write_junit",
    "junit_xml",
    "write_html",
    "html_report",
    "format_difference",
    "verdict",
    "profile_of",
    "svg_plot",
    "clean_text",
]
