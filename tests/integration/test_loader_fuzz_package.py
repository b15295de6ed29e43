"""The loader fuzzer's package target (fuzz/loaders.py) on the session's certified
package: a few seconds with a fixed seed find no traceback in package verification."""

from __future__ import annotations

from fbaconf.certification.package import SUMS, verify
from fbaconf.fuzz import loaders

SECONDS = 4.0  # a cap: the input count below ends it first on an idle machine


def test_package_verification_gives_typed_errors_only(certified_package, tmp_path):
    target = loaders.PackageTarget(tmp_path, certified_package)
    assert SUMS in target.names and "certificate.json" in target.names and "suites/simple-l1-core.json" in target.names
    st = loaders.fuzz(target, SECONDS, seed=29, max_inputs=25)
    assert st.inputs > 0
    assert st.findings == {}, "\n".join(tb for _, tb in st.findings.values())
    assert verify(target.pkg).problems == []  # each input is undone before the next


def test_verify_reports_an_unnameable_listed_file_as_a_problem(certified_package):
    sums = certified_package / SUMS
    sums.write_bytes(sums.read_bytes() + b"0" * 64 + b"  " + b"x" * 300 + b"\n")
    problems = verify(certified_package).problems
    assert any("longer than 255 bytes" in p for p in problems), problems
