"""A JVM decoder (item 4): a tiny Java program compiled here with javac (skipped
cleanly where there is no JDK). Under ``memory_kind = "address-space"`` and 2048 MB the JVM
cannot start — "Could not allocate compressed class space", printed on **stdout** — and every
case read "java exited with code 1, a reject: a valid stream was rejected". A jar given as an
argument outside the program's and the manifest's folders was invisible ("Unable to access
jarfile"), a Fail per case. Now: the first is one set-up error naming the JVM's words and the
fix (proven by the canary's run without the limit); the named jar's folder is shown (checked)
and the decoder runs; a jar the command does not name (a ``Class-Path`` entry outside every
shown folder) is one set-up error naming the JVM's words and the fix. Never a Fail.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from lib.manifests import write_manifest
from lib.sandbox import needs_sandbox

DEC = """import java.nio.file.*;
public class Dec {
    public static void main(String[] a) throws Exception {
        byte[] d = Files.readAllBytes(Paths.get(a[0]));
        Files.writeString(Paths.get(a[1]), "not a decoding: " + d.length + " bytes\\n");
    }
}
"""
CASES = ["--case", "simple-l1-core/arith-q1-all-faps", "--case", "simple-l1-core/dct-q4"]


@pytest.fixture(scope="module")
def jars(tmp_path_factory) -> Path:
    javac, jar = shutil.which("javac"), shutil.which("jar")
    if javac is None or jar is None or shutil.which("java") is None:
        pytest.skip("no JDK (javac, jar, java) here")
    needs_sandbox()
    d = tmp_path_factory.mktemp("jvm")
    (d / "src").mkdir()
    (d / "src" / "Dec.java").write_text(DEC)
    subprocess.run([javac, "-d", str(d / "classes"), str(d / "src" / "Dec.java")], check=True, timeout=300)
    (d / "jars").mkdir()  # the decoder's jar: outside the program's (/usr/bin) and the manifest's folders
    (d / "main.txt").write_text("Main-Class: Dec\n")
    subprocess.run(
        [jar, "cfm", str(d / "jars" / "dec.jar"), str(d / "main.txt"), "-C", str(d / "classes"), "."],
        check=True,
        timeout=300,
    )
    (d / "libs").mkdir()  # a launcher whose Class-Path names a jar the command does not
    shutil.copyfile(d / "jars" / "dec.jar", d / "libs" / "dec-lib.jar")
    (d / "launcher.txt").write_text(f"Main-Class: Dec\nClass-Path: file:{d / 'libs' / 'dec-lib.jar'}\n")
    (d / "empty").mkdir()
    (d / "vendor").mkdir()
    subprocess.run(
        [jar, "cfm", str(d / "vendor" / "launcher.jar"), str(d / "launcher.txt"), "-C", str(d / "empty"), "."],
        check=True,
        timeout=300,
    )
    return d


def manifest(d: Path, name: str, jar: str, limits: str) -> Path:
    decode = ["java", "-jar", jar, "{input}", "{faps_out}"]
    return write_manifest(d / "vendor" / f"{name}.toml", decode, name="acme-java", limits=f"timeout_s = 60\n{limits}")


def fbaconf(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "fbaconf", *map(str, args)], capture_output=True, text=True, timeout=600
    )


def test_a_jvm_under_an_address_space_limit_is_one_set_up_error_with_its_words_and_the_fix(jars, tmp_path):
    m = manifest(jars, "as", str(jars / "jars" / "dec.jar"), 'memory_kind = "address-space"\nmemory_mb = 2048\n')
    r = fbaconf("run", "--decoder", m, *CASES, "-o", tmp_path / "run")
    assert r.returncode == 2, r.stdout + r.stderr
    err = r.stderr
    assert err.count("fbaconf run: error: ") == 1 and "acme-java cannot run as set up" in err
    assert "acme-java exited with code 1" in err and not re.search(r"(?<![\w-])java exited", err)  # its name
    assert "its stdout:\n    | Error occurred during initialization of VM" in err  # the JVM's words, from stdout
    assert "| Could not allocate compressed class space" in err
    assert "it decodes the same stream without the address-space limit" in err and 'memory_kind = "tree"' in err
    assert "memory: 2048 MB of address space per process (RLIMIT_AS, as the manifest asks)" in err
    assert not (tmp_path / "run" / "results.jsonl").exists()  # no Fail: no case counted
    r = fbaconf("certify", "--decoder", m, "--claim", "simple@1", "--no-speed", "-o", tmp_path / "pkg")
    assert r.returncode == 2 and "Could not allocate compressed class space" in r.stderr
    assert not (tmp_path / "pkg" / "certificate.json").exists()


def test_a_jar_named_outside_the_shown_folders_is_usable(jars, tmp_path):
    """Its folder is shown (it holds nothing but the decoder's jar): the JVM runs it and each case
    is judged on its output — a Fail for what it wrote, never "Unable to access jarfile"."""
    m = manifest(jars, "named", str(jars / "jars" / "dec.jar"), 'memory_kind = "rss"\nmemory_mb = 2048\n')
    r = fbaconf("run", "--decoder", m, *CASES, "-o", tmp_path / "run", "-j", "1")
    assert r.returncode == 1, r.stdout + r.stderr
    results = (tmp_path / "run" / "results.jsonl").read_text()
    assert results.count('"exit_code": 0') == 2 and "Unable to access jarfile" not in results


def test_a_jar_the_command_does_not_name_is_one_set_up_error_with_the_jvms_words(jars, tmp_path):
    m = manifest(jars, "classpath", "{manifest_dir}/launcher.jar", 'memory_kind = "rss"\nmemory_mb = 2048\n')
    r = fbaconf("run", "--decoder", m, *CASES, "-o", tmp_path / "run")
    assert r.returncode == 2, r.stdout + r.stderr
    err = r.stderr
    assert "acme-java cannot run as set up" in err and "| Error: Could not find or load main class Dec" in err
    assert "a file the decoder opens that its command does not name (a jar on a Class-Path" in err
    assert not (tmp_path / "run" / "results.jsonl").exists()
