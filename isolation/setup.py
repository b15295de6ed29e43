"""Set-up failures recognised by behaviour, never by a runtime's wording.

A decoder that cannot start — a JVM that cannot allocate its class space under an
address-space limit (it says so on *stdout*), a jar or library the sandbox does not show, a
runtime outside the folders shown — fails every case the same way. Read case by case, each
looks like the decoder's verdict on a stream ("exited with code 1, a reject"), and a claim
fails for what is the lab's set-up. Two checks by behaviour turn that into one set-up error
(:class:`SetupError`: exit 2, no case counted, no certificate), reported with the program's
stdout and stderr, the limits in force and the likely fix (:func:`report`):

* **the canary** (:func:`probe`; the harness picks the claim's simplest valid stream and runs
  it exactly as a case runs, :func:`fbaconf.harness.preflight.canary`): any ending but a decoding (exit 0,
  no crash report) or "not supported" (exit 69) is a set-up error. Where an address-space
  limit was in force, the stream runs once more without it (``memory_kind = "rss"``: the same
  megabytes, sampled over the tree, and the cgroup where there is one); when it then decodes,
  the limit is the cause and the fix is said as a fact.
* **identical endings** (:func:`identical`), after the cases: at least two cases ran the
  decoder, one on a valid stream, none decoded, and every one ended the same way — the same
  ending, exit code and signal, the same stderr once each case's file names are normalised.
  An invalid stream's reject passes and a valid one's fails: endings are compared, not outcomes.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Iterable
from dataclasses import replace
from pathlib import Path

from fbaconf.errors import FbaconfInputError

from . import bounds, endings, sandbox
from .process import Note
from .sandbox import Limits, View
from .subject import Ended

HEAD_LINES, TAIL_LINES = 5, 10  # of stdout and stderr in a set-up error: a runtime's first words and its last
_FINE = (endings.EndingKind.DECODED, endings.EndingKind.NOT_SUPPORTED)


class SetupError(FbaconfInputError):
    """The decoder cannot run here as set up (exit 2): its own words, the limits, the fix."""

    rule = "decoder-setup"


def probe(  # noqa: PLR0913 - what sandbox.run takes, and what names the run in the error
    argv: list[str],
    workdir: Path,
    limits: Limits,
    *,
    name: str,
    what: str,
    file: str,
    env: dict[str, str] | None = None,
    view: View | None = None,
    reject_exit_codes: Collection[int] = endings.DEFAULT_REJECT_EXIT_CODES,
) -> None:
    """Run ``argv`` once as a case runs (``run``: :func:`~.sandbox.run`'s ``env``, ``view``, and
    ``reject_exit_codes``); raise :class:`SetupError` (naming ``what`` was run) unless it decodes
    or answers "not supported"."""
    codes = reject_exit_codes
    res = sandbox.run(argv, workdir, limits, env=env, view=view)
    ending = endings.classify(res, limits, codes, name=name)
    if ending.kind in _FINE:
        return
    fixes = []
    if Note.AS_LIMIT in res.notes:
        again = endings.classify(
            sandbox.run(argv, workdir, replace(limits, memory_kind="rss"), env=env, view=view), limits, codes, name=name
        )
        if again.kind in _FINE:
            fixes.append(
                f"it decodes the same stream without the address-space limit: the runtime cannot start "
                f"under {limits.memory_mb} MB of address space per process (it reserves address space up "
                f'front). Fix: memory_kind = "tree" in [limits] (the whole tree\'s use, where cgroups are '
                f'writable) or "rss" (sampled)'
            )
    raise SetupError(
        report(name, limits, f"{what} did not decode: {ending.message}", res.stdout_tail, res.stderr_tail, fixes),
        file=file,
    )


def report(name: str, limits: Limits, what: str, stdout: str, stderr: str, fixes: list[str]) -> str:
    """The set-up error's text: what happened, the program's own words, the limits, the fix."""
    if not fixes:
        fixes = [
            "a runtime or library outside the folders the sandbox shows (the program's folder, the folders "
            "of the files its command names, the manifest's folder, /usr, /etc, /bin, /lib*): the lab gives "
            "its folder with --sandbox-ro DIR",
            "a file the decoder opens that its command does not name (a jar on a Class-Path, a model, an "
            "argument file): name it in [commands] (its folder is then shown, checked) or keep it beside the "
            "program",
            f'memory: memory_kind (now "{limits.memory_kind}") and memory_mb (now {limits.memory_mb})',
        ]
    lines = [f"{name} cannot run as set up: {what}. No case was counted; this is not a verdict on a stream."]
    for which, text in (("stdout", stdout), ("stderr", stderr)):
        said = [ln for ln in (text or "").splitlines() if ln.strip()]
        if len(said) > HEAD_LINES + TAIL_LINES:
            said = said[:HEAD_LINES] + [f"… ({len(said) - HEAD_LINES - TAIL_LINES} lines)"] + said[-TAIL_LINES:]
        lines.append(f"  its {which}:" + ("" if said else " (empty)"))
        lines += [f"    | {ln[:300]}" for ln in said]
    lines.append("  limits in force: " + "; ".join(bounds.in_force(limits)))
    lines.append("  likely fix:")
    lines += [f"    - {f}" for f in fixes]
    return "\n".join(lines)


_WORKDIR = re.compile(r"/[^\s'\"]*/case-[A-Za-z0-9_]+")
_KILLED = ("Timeout", "Crash", "Error")  # outcomes that are the ending itself


def _key(r: Ended) -> tuple[str, int | None, str | None, str | None, str]:
    """How one case's process ended, its own file names normalised (a case result's fields)."""
    text = _WORKDIR.sub("<case>", r.stderr_tail or "").replace(r.case_id.split("/", 1)[-1], "<input>")
    how = r.outcome.value if r.outcome.value in _KILLED else "exited"
    return how, r.exit_code, r.signal, r.crash_kind, text.strip()


def identical(name: str, limits: Limits, results: Iterable[Ended], valid: set[str]) -> str | None:
    """The set-up error's text when every result that ran the decoder ended the same way and
    none decoded (module doc), else None. ``valid``: the ids of the valid-stream cases."""
    ran = [r for r in results if r.outcome.value != "NotSupported"]
    if (
        len(ran) < 2
        or not any(r.case_id in valid for r in ran)
        or len({_key(r) for r in ran}) != 1
        or any(r.exit_code == 0 and r.signal is None and r.crash_kind is None for r in ran)
    ):
        return None
    first = next(r for r in ran if r.case_id in valid)
    return report(
        name,
        limits,
        f"every one of the {len(ran)} cases it ran ended the same way, none decoded ({first.case_id}: {first.message})",
        "",
        first.stderr_tail,
        [],
    )
