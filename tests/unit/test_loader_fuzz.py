"""The loader fuzzer (fuzz/loaders.py): a few seconds of each target with a fixed seed
finds no traceback in the manifest and suite loaders, and a loader that raises anything but a
typed error is reported (the package target, which needs a certified package, is in
tests/integration/test_loader_fuzz_package.py). The 10-minute campaign is a documented command
(``python -m fbaconf.fuzz.loaders``), not a test."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from fbaconf.errors import FbaconfInputError
from fbaconf.fuzz import loaders
from fbaconf.safefs import PathEscapeError, confined

SECONDS = 4.0  # per target: a cap, the input count below ends it first on an idle machine


def _no_tracebacks(st: loaders.Stats) -> None:
    assert st.inputs > 0
    assert st.findings == {}, "\n".join(tb for _, tb in st.findings.values())


def test_manifest_loader_gives_typed_errors_only(tmp_path):
    _no_tracebacks(loaders.fuzz(loaders.ManifestTarget(tmp_path), SECONDS, seed=29, max_inputs=400))


def test_suite_loader_gives_typed_errors_only(tmp_path):
    _no_tracebacks(loaders.fuzz(loaders.SuiteTarget(tmp_path), SECONDS, seed=29, max_inputs=200))


class _Raising(loaders.Target):
    """A loader with one typed refusal and one bug: the bug is the only finding."""

    name = "raising"

    def seeds(self):
        return [b"typed", b"bug"]

    def mutate(self, rng, data, pool):
        return data

    def load(self, data):
        if data == b"bug":
            {}["missing"]
        raise FbaconfInputError("refused", rule="manifest-toml")


def test_a_traceback_is_a_finding_and_a_typed_error_is_not(tmp_path):
    st = loaders.fuzz(_Raising(tmp_path), 5.0, seed=1, max_inputs=40)
    assert st.inputs == 40
    assert list(st.findings) == [f"KeyError@test_loader_fuzz.py:{_Raising.load.__code__.co_firstlineno + 2}"]
    data, tb = st.findings[next(iter(st.findings))]
    assert data == b"bug" and "KeyError: 'missing'" in tb


def test_a_target_without_seeds_is_a_typed_error(tmp_path):
    class Empty(_Raising):
        def seeds(self):
            return []

    with pytest.raises(FbaconfInputError) as e:
        loaders.fuzz(Empty(tmp_path), 1.0, seed=1)
    assert e.value.rule == "fuzz-setup"


# confined(): names the file system cannot hold are refused as escapes, not OSError (a package's
# SHA256SUMS may list anything)
def test_confined_refuses_a_component_over_255_bytes_and_quotes_80_characters(tmp_path):
    rel = "a" * 300
    with pytest.raises(PathEscapeError) as e:
        confined(tmp_path, rel, what="entry")
    assert "longer than 255 bytes" in e.value.message
    assert "a" * 81 not in e.value.message and "(300 characters)" in e.value.message


def test_confined_refuses_a_path_the_file_system_cannot_resolve(tmp_path):
    deep = "/".join(["d"] * 3000)  # every part short, the whole over PATH_MAX (4096)
    try:
        out = confined(tmp_path, deep)
    except PathEscapeError as e:
        assert "d/d/d" in e.message
    else:  # a kernel that takes it: the path must still be inside
        assert str(out).startswith(str(tmp_path))


def test_long_component_is_counted_in_bytes_not_characters(tmp_path):
    rel = "\u00e9" * 200  # 200 characters, 400 bytes in UTF-8
    assert len(os.fsencode(rel)) == 400
    with pytest.raises(PathEscapeError):
        confined(tmp_path, rel)
    assert confined(tmp_path, "\u00e9" * 100) == Path(tmp_path) / ("\u00e9" * 100)
